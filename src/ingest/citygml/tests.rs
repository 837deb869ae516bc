//! Reader tests on small documents written here: ImplicitGeometry placements (CityGML 2.0
//! clause 8.2) and their prototype's appearance, and the features and geometry of an Application
//! Domain Extension.

use super::*;
use crate::scene::ComponentId;

fn read(xml: &str) -> CityModel {
    read_citygml_bytes(
        Path::new("test.gml"),
        xml.as_bytes(),
        CityGmlOptions::default(),
    )
    .unwrap()
}

/// Every drawn vertex of a component, in the scene's frame.
fn world_vertices(scene: &Scene, c: usize) -> Vec<DVec3> {
    let component = &scene.components[c];
    let mesh = scene.mesh(component.mesh);
    mesh.primitives
        .iter()
        .flat_map(|p| p.positions.iter())
        .map(|v| {
            component
                .world
                .transform_point3(DVec3::from_array(v.map(f64::from)))
        })
        .collect()
}

fn has_vertex(vertices: &[DVec3], v: DVec3) -> bool {
    vertices.iter().any(|x| (*x - v).length() < 1e-3)
}

const HEAD: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:gml="http://www.opengis.net/gml"
  xmlns:frn="http://www.opengis.net/citygml/cityfurniture/2.0" xmlns:xlink="http://www.w3.org/1999/xlink"
  xmlns:bldg="http://www.opengis.net/citygml/building/2.0" xmlns:x="http://example.org/ade/1.0">"#;

/// A lamp post's prototype: a unit square in x-z (a vertical panel), by the reference point.
const PANEL: &str = r#"<gml:MultiSurface gml:id="panel"><gml:surfaceMember><gml:Polygon><gml:exterior>
  <gml:LinearRing><gml:posList srsDimension="3">0 0 0 1 0 0 1 0 1 0 0 1 0 0 0</gml:posList></gml:LinearRing>
  </gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"#;

#[test]
fn implicit_geometries_are_placed_by_their_matrix_and_reference_point() {
    // The first places the prototype inline, turned 90 degrees about z, scaled by 2 and moved
    // 10 m up by the matrix's last column; the second reaches it by xlink, as it is.
    let xml = format!(
        r##"{HEAD}
<cityObjectMember><frn:CityFurniture gml:id="lamp-1"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>0 -2 0 0 2 0 0 0 0 0 2 10 0 0 0 1</transformationMatrix>
  <referencePoint><gml:Point srsName="EPSG:25832"><gml:pos>500000 5400000 100</gml:pos></gml:Point></referencePoint>
  <relativeGMLGeometry>{PANEL}</relativeGMLGeometry>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
<cityObjectMember><frn:CityFurniture gml:id="lamp-2"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</transformationMatrix>
  <referencePoint><gml:Point><gml:pos>500020 5400000 100</gml:pos></gml:Point></referencePoint>
  <relativeGMLGeometry xlink:href="#panel"/>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
</CityModel>"##
    );
    let model = read(&xml);
    let scene = &model.scene;
    assert!(
        model.map_crs.is_some(),
        "a projected CRS is placed per vertex later"
    );
    assert_eq!(
        scene.components.len(),
        2,
        "each placement draws, the prototype alone does not"
    );
    assert!(
        scene.reader_warnings.is_empty(),
        "{:?}",
        scene.reader_warnings
    );
    let first = world_vertices(scene, 0);
    let o = DVec3::new(500000.0, 5400000.0, 100.0);
    // (1, 0, 1) -> x' = -2*0 = 0, y' = 2*1 = 2, z' = 2*1 + 10 = 12.
    for (v, expected) in [
        (DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.0, 0.0, 10.0)),
        (DVec3::new(1.0, 0.0, 1.0), DVec3::new(0.0, 2.0, 12.0)),
        (DVec3::new(0.0, 0.0, 1.0), DVec3::new(0.0, 0.0, 12.0)),
    ] {
        assert!(
            has_vertex(&first, o + expected),
            "{v} -> {expected}: {first:?}"
        );
    }
    let second = world_vertices(scene, 1);
    assert!(
        has_vertex(&second, DVec3::new(500021.0, 5400000.0, 101.0)),
        "{second:?}"
    );
    assert_eq!(scene.element(ComponentId(1)).key, "lamp-2");
}

#[test]
fn an_implicit_geometry_without_a_prototype_here_is_a_warning() {
    let xml = format!(
        r#"{HEAD}
<cityObjectMember><frn:CityFurniture gml:id="sign"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <mimeType>model/vrml</mimeType><libraryObject>http://example.org/sign.wrl</libraryObject>
  <transformationMatrix>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</transformationMatrix>
  <referencePoint><gml:Point><gml:pos>1 2 3</gml:pos></gml:Point></referencePoint>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
<cityObjectMember><frn:CityFurniture gml:id="bench"><frn:lod1Geometry>{PANEL}</frn:lod1Geometry>
</frn:CityFurniture></cityObjectMember>
</CityModel>"#
    );
    let scene = read(&xml).scene;
    assert_eq!(scene.components.len(), 1);
    assert!(
        scene
            .reader_warnings
            .iter()
            .any(|w| w.contains("test.gml") && w.contains("1 ImplicitGeometry")),
        "{:?}",
        scene.reader_warnings
    );
    let bad = format!(
        r#"{HEAD}<cityObjectMember><frn:CityFurniture gml:id="s"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>1 0 0</transformationMatrix></ImplicitGeometry></frn:lod2ImplicitRepresentation>
  </frn:CityFurniture></cityObjectMember></CityModel>"#
    );
    let e = read_citygml_bytes(
        Path::new("m.gml"),
        bad.as_bytes(),
        CityGmlOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("m.gml") && e.contains("line 5") && e.contains("not 16"),
        "{e}"
    );
}

#[test]
fn ade_features_and_geometry_are_elements() {
    // An ADE boundary surface of a building, an ADE feature inside it with an ADE geometry
    // property, an ADE record with an id but no geometry (its fields go to the building), and
    // an ADE attribute named like a LoD that stays an attribute.
    let square = |z: f64| {
        format!(
            r#"<gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing>
  <gml:posList>0 0 {z} 4 0 {z} 4 4 {z} 0 4 {z} 0 0 {z}</gml:posList></gml:LinearRing></gml:exterior>
  </gml:Polygon></gml:surfaceMember></gml:MultiSurface>"#
        )
    };
    let xml = format!(
        r#"{HEAD}
<cityObjectMember><bldg:Building gml:id="b">
  <x:lod1HeightType>measured</x:lod1HeightType>
  <x:certificate><x:Certificate gml:id="cert"><x:grade>A</x:grade></x:Certificate></x:certificate>
  <bldg:boundedBy><x:SolarRoofSurface gml:id="roof"><bldg:lod2MultiSurface>{}</bldg:lod2MultiSurface>
  </x:SolarRoofSurface></bldg:boundedBy>
  <x:unit><x:Flat gml:id="flat"><x:floor>2</x:floor><x:lod2MultiSurface>{}</x:lod2MultiSurface></x:Flat></x:unit>
</bldg:Building></cityObjectMember>
</CityModel>"#,
        square(10.0),
        square(3.0)
    );
    let scene = read(&xml).scene;
    assert_eq!(scene.components.len(), 2, "the building and its flat");
    let keys: Vec<String> = (0..2)
        .map(|c| scene.element(ComponentId(c)).key.clone())
        .collect();
    assert_eq!(keys, ["b", "flat"]);
    let flat = world_vertices(&scene, 1);
    assert!(flat.iter().all(|v| (v.z - 3.0).abs() < 1e-6), "{flat:?}");
    assert_eq!(scene.node_path(scene.components[1].node.unwrap()), "b/flat");
    let names = |c: u32| -> Vec<String> {
        let info = scene.element(ComponentId(c));
        info.properties.iter().map(|p| p.name.to_string()).collect()
    };
    let building = names(0);
    for wanted in ["x:lod1HeightType", "x:grade", "SolarRoofSurface"] {
        assert!(
            building.iter().any(|n| n == wanted),
            "{wanted} in {building:?}"
        );
    }
    assert!(names(1).iter().any(|n| n == "x:floor"), "{:?}", names(1));
}

#[test]
fn a_prototype_placed_in_a_geographic_crs_keeps_its_metres() {
    // Latitude first (EPSG:6697): the offsets are metres east, north and up of the point.
    let xml = format!(
        r#"{HEAD}
<cityObjectMember><frn:CityFurniture gml:id="post"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>3 0 0 0 0 3 0 0 0 0 3 0 0 0 0 1</transformationMatrix>
  <referencePoint><gml:Point srsName="http://www.opengis.net/def/crs/EPSG/0/6697"><gml:pos>35.3 139.7 20</gml:pos></gml:Point></referencePoint>
  <relativeGMLGeometry>{PANEL}</relativeGMLGeometry>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
</CityModel>"#
    );
    let model = read(&xml);
    let scene = &model.scene;
    let georeference = scene.georeference.as_ref().expect("placed on the globe");
    assert!(
        (georeference.latitude_deg - 35.3).abs() < 1e-6,
        "{georeference:?}"
    );
    assert!(
        (georeference.longitude_deg - 139.7).abs() < 1e-6,
        "{georeference:?}"
    );
    let v = world_vertices(scene, 0);
    let (min, max) = v
        .iter()
        .fold((DVec3::MAX, DVec3::MIN), |(a, b), p| (a.min(*p), b.max(*p)));
    let size = max - min;
    assert!(
        (size.x - 3.0).abs() < 1e-3 && size.y.abs() < 1e-3 && (size.z - 3.0).abs() < 1e-3,
        "{size}"
    );
}

/// A square roof of 8 m at (1000, 2000) under a georeferenced 4x4 image of 2 m pixels, placed
/// by the texture itself or by a world file beside the image.
fn georeferenced_roof(placement: &str, world_file: Option<&str>) -> Scene {
    let dir = tempfile::tempdir().unwrap();
    image::RgbImage::from_pixel(4, 4, image::Rgb([200, 40, 40]))
        .save(dir.path().join("ortho.png"))
        .unwrap();
    if let Some(w) = world_file {
        std::fs::write(dir.path().join("ortho.pgw"), w).unwrap();
    }
    let xml = format!(
        r##"{HEAD}
<cityObjectMember><bldg:Building gml:id="b"><bldg:lod2MultiSurface><gml:MultiSurface gml:id="roof">
  <gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing>
  <gml:posList>1000 1992 10 1008 1992 10 1008 2000 10 1000 2000 10 1000 1992 10</gml:posList>
  </gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>
</bldg:lod2MultiSurface></bldg:Building></cityObjectMember>
<appearanceMember xmlns:app="http://www.opengis.net/citygml/appearance/2.0"><app:Appearance>
  <app:theme>ortho</app:theme><app:surfaceDataMember><app:GeoreferencedTexture>
  <app:imageURI>ortho.png</app:imageURI>{placement}<app:target>#roof</app:target>
  </app:GeoreferencedTexture></app:surfaceDataMember></app:Appearance></appearanceMember>
</CityModel>"##
    );
    let path = dir.path().join("roof.gml");
    std::fs::write(&path, xml).unwrap();
    read_citygml(&path, CityGmlOptions::default())
        .unwrap()
        .scene
}

/// The UV at each corner of the roof.
fn corner_uvs(scene: &Scene) -> Vec<(DVec3, [f32; 2])> {
    let component = &scene.components[0];
    let mesh = scene.mesh(component.mesh);
    let p = &mesh.primitives[0];
    let uvs = p.uvs.as_ref().expect("textured");
    p.positions
        .iter()
        .zip(uvs)
        .map(|(v, uv)| {
            (
                component
                    .world
                    .transform_point3(DVec3::from_array(v.map(f64::from))),
                *uv,
            )
        })
        .collect()
}

#[test]
fn georeferenced_textures_lie_over_their_surfaces() {
    // The upper-left pixel's centre at (1001, 1999), 2 m a pixel, rows going south.
    let own = r#"<app:referencePoint><gml:Point><gml:pos>1001 1999</gml:pos></gml:Point></app:referencePoint>
      <app:orientation>2 0 0 -2</app:orientation>"#;
    let world = "2\n0\n0\n-2\n1001\n1999\n";
    for scene in [
        georeferenced_roof(own, None),
        georeferenced_roof(
            "<app:preferWorldFile>true</app:preferWorldFile>",
            Some(world),
        ),
        georeferenced_roof("", Some(world)),
    ] {
        assert_eq!(scene.images.len(), 1);
        for (v, uv) in corner_uvs(&scene) {
            // The roof covers the image exactly: west edge u = 0, north edge v = 0.
            let expected = [((v.x - 1000.0) / 8.0) as f32, ((2000.0 - v.y) / 8.0) as f32];
            assert!(
                (uv[0] - expected[0]).abs() < 1e-5 && (uv[1] - expected[1]).abs() < 1e-5,
                "{v}: {uv:?} vs {expected:?}"
            );
        }
    }
    let unplaced = georeferenced_roof("", None);
    assert!(unplaced.images.is_empty(), "no placement, no image");
    let roof = &unplaced.components[0];
    assert!(unplaced.mesh(roof.mesh).primitives[0].uvs.is_none());
}

/// A prototype whose polygon and ring have gml:ids for appearances to target: the unit panel.
const NAMED_PANEL: &str = r#"<gml:MultiSurface gml:id="panel"><gml:surfaceMember><gml:Polygon gml:id="panel-face">
  <gml:exterior><gml:LinearRing gml:id="panel-ring"><gml:posList srsDimension="3">0 0 0 1 0 0 1 0 1 0 0 1 0 0 0</gml:posList>
  </gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"#;

/// The named panel placed twice (inline, then by xlink) with these matrices at these reference
/// points, and `surface_data` (an app:_SurfaceData) in a city model's appearance.
fn placed_twice(matrices: [&str; 2], references: [DVec3; 2], surface_data: &str) -> String {
    let pos = |v: DVec3| format!("{} {} {}", v.x, v.y, v.z);
    format!(
        r##"{HEAD}
<cityObjectMember><frn:CityFurniture gml:id="sign-1"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>{}</transformationMatrix>
  <referencePoint><gml:Point><gml:pos>{}</gml:pos></gml:Point></referencePoint>
  <relativeGMLGeometry>{NAMED_PANEL}</relativeGMLGeometry>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
<cityObjectMember><frn:CityFurniture gml:id="sign-2"><frn:lod2ImplicitRepresentation><ImplicitGeometry>
  <transformationMatrix>{}</transformationMatrix>
  <referencePoint><gml:Point><gml:pos>{}</gml:pos></gml:Point></referencePoint>
  <relativeGMLGeometry xlink:href="#panel"/>
</ImplicitGeometry></frn:lod2ImplicitRepresentation></frn:CityFurniture></cityObjectMember>
<app:appearanceMember xmlns:app="http://www.opengis.net/citygml/appearance/2.0"><app:Appearance>
  <app:theme>looks</app:theme><app:surfaceDataMember>{surface_data}</app:surfaceDataMember>
</app:Appearance></app:appearanceMember>
</CityModel>"##,
        matrices[0],
        pos(references[0]),
        matrices[1],
        pos(references[1]),
    )
}

/// The materials of a component's primitives.
fn materials_of(scene: &Scene, c: usize) -> Vec<crate::scene::MaterialId> {
    let mesh = scene.mesh(scene.components[c].mesh);
    mesh.primitives
        .iter()
        .map(|p| p.material.expect("a material"))
        .collect()
}

#[test]
fn a_prototype_material_is_worn_by_every_placement() {
    // The second copy is the first turned 90 degrees about z.
    let xml = placed_twice(
        [
            "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1",
            "0 -1 0 0 1 0 0 0 0 0 1 0 0 0 0 1",
        ],
        [DVec3::new(100.0, 200.0, 5.0), DVec3::new(120.0, 200.0, 5.0)],
        r#"<app:X3DMaterial><app:diffuseColor>0.2 0.4 0.6</app:diffuseColor>
  <app:transparency>0.5</app:transparency><app:target>#panel-face</app:target></app:X3DMaterial>"#,
    );
    let scene = read(&xml).scene;
    assert_eq!(scene.components.len(), 2);
    let expected = [0.2f32.powf(2.2), 0.4f32.powf(2.2), 0.6f32.powf(2.2), 0.5];
    for c in 0..2 {
        let materials = materials_of(&scene, c);
        assert_eq!(materials.len(), 1, "copy {c}: {materials:?}");
        let colour = scene.materials[materials[0].0 as usize].base_color;
        for (got, want) in colour.iter().zip(expected) {
            assert!(
                (got - want).abs() < 1e-5,
                "copy {c}: {colour:?} vs {expected:?}"
            );
        }
    }
    // One material for both: the copies stay alike for dedup (tests/citygml.rs).
    assert_eq!(materials_of(&scene, 0), materials_of(&scene, 1));
}

#[test]
fn a_prototype_texture_is_worn_by_every_placement() {
    let dir = tempfile::tempdir().unwrap();
    image::RgbImage::from_pixel(2, 2, image::Rgb([40, 200, 40]))
        .save(dir.path().join("sign.png"))
        .unwrap();
    // CityGML's (s, t) = the panel's own (x, z): t up, glTF's v down.
    let references = [DVec3::new(100.0, 200.0, 5.0), DVec3::new(130.0, 210.0, 5.0)];
    let identity = "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1";
    let xml = placed_twice(
        [identity, identity],
        references,
        r##"<app:ParameterizedTexture><app:imageURI>sign.png</app:imageURI>
  <app:target uri="#panel-face"><app:TexCoordList>
  <app:textureCoordinates ring="#panel-ring">0 0 1 0 1 1 0 1 0 0</app:textureCoordinates>
  </app:TexCoordList></app:target></app:ParameterizedTexture>"##,
    );
    let path = dir.path().join("signs.gml");
    std::fs::write(&path, xml).unwrap();
    let scene = read_citygml(&path, CityGmlOptions::default())
        .unwrap()
        .scene;
    assert_eq!(scene.images.len(), 1);
    assert_eq!(scene.components.len(), 2);
    for (c, reference) in references.iter().enumerate() {
        let component = &scene.components[c];
        let p = &scene.mesh(component.mesh).primitives[0];
        let material = &scene.materials[p.material.expect("a material").0 as usize];
        assert!(material.base_color_texture.is_some(), "copy {c} textured");
        let uvs = p.uvs.as_ref().expect("copy has UVs");
        assert_eq!(uvs.len(), p.positions.len());
        for (v, uv) in p.positions.iter().zip(uvs) {
            let local = component
                .world
                .transform_point3(DVec3::from_array(v.map(f64::from)))
                - *reference;
            let expected = [local.x as f32, (1.0 - local.z) as f32];
            assert!(
                (uv[0] - expected[0]).abs() < 1e-5 && (uv[1] - expected[1]).abs() < 1e-5,
                "copy {c} at {local}: {uv:?} vs {expected:?}"
            );
        }
    }
}
