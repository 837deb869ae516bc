//! Bad input: every case gives a clear one-line error naming the file, a non-zero exit, no panic,
//! and leaves no output (not even a temporary folder). What is not a regular file, or leads out of
//! the input's folder, is refused before it is read.

use crate::common::*;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Runs convert on `input` and checks the failure contract; returns stderr.
fn expect_failure(input: &Path, case: &str, must_mention: &[&str]) -> String {
    expect_failure_with(input, case, &[], must_mention)
}

/// [`expect_failure`] with extra options.
fn expect_failure_with(input: &Path, case: &str, extra: &[&str], must_mention: &[&str]) -> String {
    let dir = input.parent().unwrap();
    let out = dir.join(format!("out-{case}"));
    let mut args = vec![
        "convert",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let o = run(&args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success(), "{case}: must fail");
    assert_eq!(
        o.status.code(),
        Some(1),
        "{case}: exit code 1, not a crash: {err}"
    );
    assert!(!err.contains("panicked"), "{case}: panic: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{case}: one line: {err}");
    let name = input.file_name().unwrap().to_string_lossy();
    assert!(err.contains(name.as_ref()), "{case}: names the file: {err}");
    for m in must_mention {
        assert!(err.contains(m), "{case}: mentions '{m}': {err}");
    }
    assert!(!out.exists(), "{case}: no output written");
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp-"))
        .collect();
    assert!(leftovers.is_empty(), "{case}: temporary folder left behind");
    err
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn tri() -> [[f32; 3]; 3] {
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
}

/// Edits the JSON chunk of a GLB.
fn edit_glb(glb_bytes: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let (mut json, bin) = glb_chunks(glb_bytes);
    edit(&mut json);
    glb(&serde_json::to_vec(&json).unwrap(), &bin)
}

#[test]
fn missing_file() {
    let d = tmpdir("bad-missing");
    expect_failure(&d.join("nope.glb"), "missing", &["no such file"]);
}

#[test]
fn not_gltf() {
    let d = tmpdir("bad-notgltf");
    let p = write(&d, "notes.glb", b"this is a text file, not a model");
    expect_failure(&p, "not-gltf", &["not a glTF"]);
}

#[test]
fn truncated_glb() {
    let d = tmpdir("bad-truncated");
    let full = std::fs::read(sample()).unwrap();
    let p = write(&d, "half.glb", &full[..full.len() / 2]);
    expect_failure(&p, "truncated", &["truncated"]);
}

#[test]
fn accessor_past_its_buffer() {
    let d = tmpdir("bad-accessor");
    let g = edit_glb(&triangle_glb(tri(), None), |j| {
        j["accessors"][0]["count"] = 3000.into()
    });
    let p = write(&d, "long_accessor.glb", &g);
    expect_failure(&p, "accessor", &["past the end"]);
}

#[test]
fn index_out_of_range() {
    let d = tmpdir("bad-index");
    let g = one_mesh_glb(
        &tri(),
        Some(&[0, 1, 7]),
        serde_json::json!([{"mesh": 0}]),
        &[0],
    );
    let p = write(&d, "bad_index.glb", &g);
    expect_failure(&p, "index", &["index 7 is out of range"]);
}

#[test]
fn nan_and_infinite_positions() {
    let d = tmpdir("bad-nan");
    let p = write(
        &d,
        "nan.glb",
        &triangle_glb(
            [[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]],
            None,
        ),
    );
    expect_failure(&p, "nan", &["not finite"]);
    let p = write(
        &d,
        "inf.glb",
        &triangle_glb(
            [[0.0, 0.0, 0.0], [f32::INFINITY, 0.0, 0.0], [0.0, 1.0, 0.0]],
            None,
        ),
    );
    expect_failure(&p, "inf", &["POSITION"]);
}

/// A .gltf whose buffer lives at `uri`.
fn gltf_with_buffer_uri(uri: &str) -> Vec<u8> {
    serde_json::to_vec(&serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": uri}]
    }))
    .unwrap()
}

#[test]
fn uris_that_escape_the_input_folder_are_refused() {
    let d = tmpdir("bad-uri");
    let inner = d.join("model");
    std::fs::create_dir_all(&inner).unwrap();
    // The file exists outside the folder: refusing it is a policy, not a missing file.
    let mut bin = Vec::new();
    for v in tri() {
        for c in v {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    std::fs::write(d.join("secret.bin"), &bin).unwrap();
    let secret = d.join("secret.bin").canonicalize().unwrap();
    for (case, uri) in [
        ("dotdot", "../secret.bin".to_string()),
        ("encoded", "%2e%2e/secret.bin".to_string()),
        ("absolute", secret.display().to_string()),
        ("file-scheme", format!("file://{}", secret.display())),
    ] {
        let p = write(&inner, &format!("{case}.gltf"), &gltf_with_buffer_uri(&uri));
        expect_failure(&p, case, &["refused"]);
    }
    // The same file inside the folder is read.
    std::fs::write(inner.join("ok.bin"), &bin).unwrap();
    let p = write(&inner, "ok.gltf", &gltf_with_buffer_uri("ok.bin"));
    let out = inner.join("out-ok");
    convert(&p, &out, &[]);
    assert!(out.join("tileset.json").exists());
}

#[test]
fn existing_output_needs_force() {
    let d = tmpdir("bad-exists");
    let p = write(&d, "tri.glb", &triangle_glb(tri(), None));
    let out = d.join("out-exists");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("tileset.json"), b"{}").unwrap();
    let o = run(&[
        "convert",
        p.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1));
    assert!(err.contains("exists") && err.contains("--force"), "{err}");
    assert_eq!(
        std::fs::read(out.join("tileset.json")).unwrap(),
        b"{}",
        "untouched"
    );
    // --force replaces a folder that holds a tileset...
    convert(&p, &out, &["--force"]);
    assert!(std::fs::read(out.join("tileset.json")).unwrap().len() > 2);
    // ...but never a folder of something else.
    let other = d.join("my-documents");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("thesis.txt"), b"precious").unwrap();
    let o = run(&[
        "convert",
        p.to_str().unwrap(),
        "--out",
        other.to_str().unwrap(),
        "--quiet",
        "--force",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("does not hold a tileset"));
    assert_eq!(
        std::fs::read(other.join("thesis.txt")).unwrap(),
        b"precious"
    );
}

#[test]
fn broken_ifc_files() {
    let d = tmpdir("bad-ifc");
    let Some(ifc) = shared_file("IfcOpenHouse_IFC4.ifc") else {
        // A small hand-written IFC stands in for the real one.
        let p = write(&d, "cut.ifc", b"ISO-10303-21;\nHEADER;\nFILE_SCHEMA(('IFC4'));\nENDSEC;\nDATA;\n#1=IFCPROJECT('0YvctVUKr0kugbFTf53O9L',$,'P',$,$,$,$,(#2),#3");
        expect_failure(&p, "ifc-truncated", &[]);
        return;
    };
    let full = std::fs::read(ifc).unwrap();
    let p = write(&d, "truncated.ifc", &full[..full.len() / 2]);
    expect_failure(&p, "ifc-truncated", &[]);
    let p = write(
        &d,
        "garbage.ifc",
        b"ISO-10303-21;\nthis is not STEP at all (((",
    );
    expect_failure(&p, "ifc-garbage", &[]);
    let text =
        String::from_utf8_lossy(&full).replace("FILE_SCHEMA(('IFC4'))", "FILE_SCHEMA(('IFC9'))");
    let p = write(&d, "schema.ifc", text.as_bytes());
    expect_failure(&p, "ifc-schema", &[]);
}

/// Image sizes are checked from the header before anything is allocated: a PNG of a few dozen
/// bytes claiming 65535 x 65535 px, or an image whose decoded pixels exceed a quarter of the
/// memory budget, is refused with the file and the image named.
#[test]
fn image_bombs_are_refused_before_decoding() {
    let dir = tmpdir("bad-image-bomb");
    let bomb = png_claiming(65535, 65535);
    assert!(bomb.len() < 100, "{} bytes", bomb.len());
    let input = write(&dir, "bomb.glb", &textured_quad_glb(&bomb));
    expect_failure(&input, "bomb", &["image 0 'photo'", "65535x65535 px"]);
    let input = write(
        &dir,
        "big.glb",
        &textured_quad_glb(&png_claiming(8000, 8000)),
    );
    expect_failure_with(
        &input,
        "budget",
        &["--memory-budget", "512M"],
        &["image 0 'photo'", "8000x8000 px", "--memory-budget"],
    );
}

/// An image that does not decode is dropped from its material with one warning naming it (not
/// under --quiet), recorded in report.json; the tiles carry no image.
#[test]
fn undecodable_images_are_dropped_with_a_warning() {
    let dir = tmpdir("bad-image-undecodable");
    let mut cut = png_image(64, 64, [200, 10, 10, 255]);
    cut.truncate(cut.len() - 30);
    let input = write(&dir, "cut.glb", &textured_quad_glb(&cut));
    let out = dir.join("out");
    let o = run(&[
        "convert",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let warnings: Vec<&str> = err.lines().filter(|l| l.starts_with("warning:")).collect();
    assert_eq!(warnings.len(), 1, "{err}");
    assert!(
        warnings[0].contains("cut.glb: image 0 'photo' cannot be decoded"),
        "{err}"
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["warnings"].as_array().unwrap().len(), 1);
    assert_eq!(report["textures"]["dropped_images"][0]["name"], "photo");
    let tiles = tileset_contents(&out);
    assert!(!tiles.is_empty());
    for (name, bytes) in tiles {
        assert!(glb_json(&bytes).get("images").is_none(), "{name}: an image");
    }
    assert!(!out.join("textures").exists());
    let quiet = dir.join("out-quiet");
    let o = run(&[
        "convert",
        input.to_str().unwrap(),
        "--out",
        quiet.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success());
    assert!(
        o.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The shared IfcOpenHouse GLB, the real model the glTF cases below patch.
fn open_house_glb() -> Option<Vec<u8>> {
    shared_file("IfcOpenHouse_IFC4.glb").map(|p| std::fs::read(p).unwrap())
}

/// `model`'s GLB with the first vertex of the first primitive's POSITION set to `value` (x).
fn with_first_position(model: &[u8], value: f32) -> Vec<u8> {
    let (json, mut bin) = glb_chunks(model);
    let accessor = &json["accessors"][json["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
        .as_u64()
        .unwrap() as usize];
    let view = &json["bufferViews"][accessor["bufferView"].as_u64().unwrap() as usize];
    let at = (view["byteOffset"].as_u64().unwrap_or(0)
        + accessor["byteOffset"].as_u64().unwrap_or(0)) as usize;
    bin[at..at + 4].copy_from_slice(&value.to_le_bytes());
    glb(&serde_json::to_vec(&json).unwrap(), &bin)
}

/// A copy of a real IFC with `from` replaced by `to` (once, and it must be there).
fn patched_ifc(ifc: &Path, from: &str, to: &str) -> Vec<u8> {
    let text = std::fs::read_to_string(ifc).unwrap();
    assert!(text.contains(from), "{from} not in {}", ifc.display());
    text.replacen(from, to, 1).into_bytes()
}

/// Absurd numbers (README, "Safety": finite and within 4e7 m, the Earth's circumference) are
/// refused with one line naming the file, the element and the value, and nothing is written:
/// positions at f32::MAX or 1e38, node transforms of 1e30 and 1e300, in a real model.
#[test]
fn absurd_gltf_numbers_are_refused() {
    let Some(model) = open_house_glb() else {
        return;
    };
    let d = tmpdir("bad-absurd-gltf");
    for (case, value, shown) in [("max", f32::MAX, "e38"), ("1e38", 1e38, "e37")] {
        let p = write(
            &d,
            &format!("{case}.glb"),
            &with_first_position(&model, value),
        );
        let err = expect_failure(&p, case, &["element '", "vertex coordinate", shown]);
        assert!(err.contains("not plausible"), "{err}");
    }
    let node_edits: [(&str, serde_json::Value, &str); 3] = [
        (
            "translation",
            serde_json::json!({"translation": [1e30, 0, 0]}),
            "1e30",
        ),
        (
            "scale",
            serde_json::json!({"scale": [1, 1e300, 1]}),
            "1e300",
        ),
        (
            "matrix",
            serde_json::json!({"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,-2e300,0,1]}),
            "2e300",
        ),
    ];
    for (case, edit, shown) in node_edits {
        let g = edit_glb(&model, |j| {
            let nodes = j["nodes"].as_array_mut().unwrap();
            let node = nodes.iter_mut().find(|n| n.get("mesh").is_some()).unwrap();
            for k in ["matrix", "translation", "rotation", "scale"] {
                node.as_object_mut().unwrap().remove(k);
            }
            node.as_object_mut()
                .unwrap()
                .extend(edit.as_object().unwrap().clone());
        });
        let p = write(&d, &format!("node-{case}.glb"), &g);
        expect_failure(&p, case, &["element '", "transform entry", shown]);
    }
}

/// A 1e30 m extrusion in a real IFC, and map conversions with a Scale of 0 or 1e300, are refused
/// by name.
#[test]
fn absurd_ifc_numbers_are_refused() {
    let (Some(haus), Some(house)) = (
        shared_file("AC20-FZK-Haus.ifc"),
        shared_file("IfcOpenHouse_IFC4.ifc"),
    ) else {
        return;
    };
    let d = tmpdir("bad-absurd-ifc");
    let line = "#15006= IFCEXTRUDEDAREASOLID(#14994,#15003,#15004,2.5);";
    let deep = line.replace("2.5)", "1.E30)");
    let p = write(&d, "deep.ifc", &patched_ifc(&haus, line, &deep));
    // ifc-lite centres the solid: its transform or its vertices hold the 1e30.
    let err = expect_failure(&p, "extrusion", &["element '", "not plausible"]);
    assert!(err.contains("e29") || err.contains("e30"), "{err}");

    let context = "#11=IFCGEOMETRICREPRESENTATIONCONTEXT('Plan','Model',3,1.E-005,#10,#6);";
    for (case, scale, shown) in [
        ("scale0", "0.", "Scale 0e0"),
        ("scale1e300", "1.E300", "Scale 1e300"),
    ] {
        let map = format!(
            "{context}\n#900001=IFCPROJECTEDCRS('EPSG:25832',$,$,$,$,$,$);\n#900002=IFCMAPCONVERSION(#11,#900001,458000.,5437000.,110.,1.,0.,{scale});"
        );
        let p = write(
            &d,
            &format!("{case}.ifc"),
            &patched_ifc(&house, context, &map),
        );
        expect_failure(
            &p,
            case,
            &["IfcMapConversion", shown, "not a plausible scale"],
        );
    }
}

/// `--origin` with a height of 1e308 or a latitude past the pole, and a manifest offset of
/// 1e300, are refused by name.
#[test]
fn absurd_placements_are_refused() {
    let d = tmpdir("bad-absurd-place");
    let p = write(&d, "sample.glb", &std::fs::read(sample()).unwrap());
    // A bad option is a usage error (exit code 2, clap's usage hint after the line).
    for (case, origin, shown) in [
        ("height", "8,49,1e308", "height 1e308"),
        ("latitude", "8,91", "latitude in [-90,90]"),
    ] {
        let out = d.join(format!("out-{case}"));
        let (input, out_arg) = (p.to_str().unwrap(), out.to_str().unwrap());
        let o = run(&["convert", input, "--out", out_arg, "--origin", origin]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.lines().next().unwrap().contains(shown), "{err}");
        assert!(!out.exists());
    }
    let manifest = serde_json::json!({"models": [{"path": "sample.glb", "east_m": 1e300}]});
    let m = write(&d, "campus.json", &serde_json::to_vec(&manifest).unwrap());
    let out = d.join("out-manifest");
    let o = run(&[
        "convert",
        "--manifest",
        m.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("campus.json") && err.contains("east_m 1e300"),
        "{err}"
    );
    assert!(!out.exists());
}

/// What the glTF 2.0 specification forbids is refused, in a real model: a GLB header length that
/// disagrees with the file, byte strides that cut elements or break the 4..=252 rule, a mesh with
/// no primitives, an asset version other than 2.x or a minVersion above 2.0.
#[test]
fn gltf_the_specification_forbids_is_refused() {
    let Some(model) = open_house_glb() else {
        return;
    };
    let d = tmpdir("bad-lenient-gltf");
    let mut longer = model.clone();
    longer.extend_from_slice(&[0; 8]);
    let p = write(&d, "longer.glb", &longer);
    expect_failure(&p, "glb-length", &["GLB header says the file has"]);

    let position_view = |j: &serde_json::Value| {
        let a = j["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
            .as_u64()
            .unwrap();
        j["accessors"][a as usize]["bufferView"].as_u64().unwrap() as usize
    };
    for (case, stride, shown) in [
        ("stride-cuts", 8, "overlap"),
        ("stride-odd", 14, "byteStride 14"),
        ("stride-big", 256, "byteStride 256"),
    ] {
        let g = edit_glb(&model, |j| {
            let v = position_view(j);
            j["bufferViews"][v]["byteStride"] = stride.into();
        });
        let p = write(&d, &format!("{case}.glb"), &g);
        expect_failure(&p, case, &[shown]);
    }
    let g = edit_glb(&model, |j| {
        j["meshes"]
            .as_array_mut()
            .unwrap()
            .push(serde_json::json!({"primitives": []}));
    });
    let p = write(&d, "no-primitives.glb", &g);
    expect_failure(&p, "no-primitives", &["no primitives"]);
    for (case, field, value) in [
        ("version-3", "version", "3.0"),
        ("version-text", "version", "2"),
        ("min-version", "minVersion", "2.1"),
    ] {
        let g = edit_glb(&model, |j| j["asset"][field] = value.into());
        let p = write(&d, &format!("{case}.glb"), &g);
        expect_failure(&p, case, &[&format!("asset.{field}"), value]);
    }
}

/// An IFC file that defines an entity id twice (a real file with one record repeated) is
/// refused, naming the id.
#[test]
fn duplicate_ifc_entity_ids_are_refused() {
    let Some(house) = shared_file("IfcOpenHouse_IFC4.ifc") else {
        return;
    };
    let d = tmpdir("bad-ifc-duplicate");
    let context = "#11=IFCGEOMETRICREPRESENTATIONCONTEXT('Plan','Model',3,1.E-005,#10,#6);";
    let twice = format!("{context}\n#11=IFCCARTESIANPOINT((0.,0.,0.));");
    let p = write(&d, "twice.ifc", &patched_ifc(&house, context, &twice));
    expect_failure(&p, "duplicate-id", &["#11 is defined twice"]);
}

/// What is not a regular file is refused at once: a FIFO would hold the run forever, a device
/// never ends.
#[test]
fn fifos_and_devices_are_refused() {
    let dir = tmpdir("safety-special");
    let fifo = dir.join("pipe.glb");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    for (input, what) in [(fifo.as_path(), "FIFO"), (Path::new("/dev/zero"), "device")] {
        let t = Instant::now();
        let o = run(&[
            "convert",
            input.to_str().unwrap(),
            "--out",
            dir.join("out").to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains(what) && err.contains(input.to_str().unwrap()),
            "{err}"
        );
        assert!(t.elapsed() < Duration::from_secs(10));
    }
    // A manifest entry and a glTF buffer URI that are FIFOs.
    std::fs::write(
        dir.join("m.json"),
        r#"{"origin": {"longitude_deg": 8, "latitude_deg": 49}, "models": [{"path": "pipe.glb"}]}"#,
    )
    .unwrap();
    let o = run(&[
        "convert",
        "--manifest",
        dir.join("m.json").to_str().unwrap(),
        "--out",
        dir.join("out").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("FIFO"));
    std::fs::write(
        dir.join("uri.gltf"),
        r#"{"asset": {"version": "2.0"}, "buffers": [{"uri": "pipe.glb", "byteLength": 12}]}"#,
    )
    .unwrap();
    let o = run(&[
        "convert",
        dir.join("uri.gltf").to_str().unwrap(),
        "--out",
        dir.join("out").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("FIFO"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A manifest entry that is a symlink inside the manifest's folder, leading out of it, is refused
/// (as glTF URIs are).
#[test]
fn manifest_symlinks_leading_out_are_refused() {
    let dir = tmpdir("safety-manifest-symlink");
    std::os::unix::fs::symlink(sample(), dir.join("outside.glb")).unwrap();
    std::fs::write(
        dir.join("m.json"),
        r#"{"models": [{"path": "outside.glb"}]}"#,
    )
    .unwrap();
    let out = dir.join("out");
    let o = run(&[
        "convert",
        "--manifest",
        dir.join("m.json").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("m.json") && err.contains("symlink leads outside"),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn broken_obj_files() {
    let d = tmpdir("bad-obj");
    let cases: &[(&str, &[u8], &[&str])] = &[
        (
            "index.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
            &["line 4", "'4'"],
        ),
        (
            "relative.obj",
            b"v 0 0 0\nf -1 -2 -3\n",
            &["line 2", "'-2'"],
        ),
        (
            "number.obj",
            b"v 0 0 0\nv 1 zero 0\n",
            &["line 2", "'zero'"],
        ),
        ("short.obj", b"v 0 0\n", &["line 1", "fewer than 3"]),
        (
            "uv.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n",
            &["line 4", "texture coordinate"],
        ),
        ("huge.obj", b"v 0 0 1e400\n", &["line 1", "'1e400'"]),
    ];
    for (name, bytes, mention) in cases {
        let p = write(&d, name, bytes);
        expect_failure(&p, name, mention);
    }
}

#[test]
fn broken_fbx_files() {
    let d = tmpdir("bad-fbx");
    let cases: &[(&str, &[u8], &[&str])] = &[
        (
            "truncated.fbx",
            b"Kaydara FBX Binary  \x00\x1a\x00\xe8\x1c\x00\x00",
            &["not a readable FBX file"],
        ),
        (
            "text.fbx",
            b"this is no FBX file",
            &["not a readable FBX file"],
        ),
    ];
    for (name, bytes, mention) in cases {
        let p = write(&d, name, bytes);
        expect_failure(&p, name, mention);
    }
}

#[test]
fn broken_citygml_files() {
    let dir = tmpdir("bad-citygml");
    let head = r#"<?xml version="1.0"?><core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0" xmlns:gml="http://www.opengis.net/gml">"#;
    let truncated = write(
        &dir,
        "truncated.gml",
        format!("{head}\n<core:cityObjectMember>").as_bytes(),
    );
    expect_failure(&truncated, "truncated", &["line 2", "ends inside"]);
    let not_city = write(&dir, "other.gml", b"<?xml version=\"1.0\"?>\n<kml></kml>");
    expect_failure(&not_city, "not-citygml", &["not a CityGML file"]);
    let bad_number = write(
        &dir,
        "number.gml",
        format!("{head}\n<core:cityObjectMember><bldg:Building gml:id=\"b\"><bldg:lod1MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing>\n<gml:posList>0 0 0 1 0 x 1 1 0 0 0 0</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface></bldg:lod1MultiSurface></bldg:Building></core:cityObjectMember></core:CityModel>").as_bytes(),
    );
    expect_failure(
        &bad_number,
        "bad-number",
        &["line 3", "'x' is not a number"],
    );
}
