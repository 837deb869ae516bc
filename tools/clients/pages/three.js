// 3DTilesRendererJS (three.js) page, bundled by esbuild at test time: loads ?tileset= with the
// GLTFExtensionsPlugin (metadata on, meshopt, Draco and KTX2 decoders served from ?lib=, i.e.
// tools/node_modules), frames it, and exposes window.client for tools/clients/three.mjs:
// state (loads, errors, per-tile copies), pick() (metadata of the feature under a pixel) and
// instancePick() (metadata of two copies of an instanced mesh).
import * as THREE from "three";
import { TilesRenderer } from "3d-tiles-renderer";
import { GLTFExtensionsPlugin, ReorientationPlugin } from "3d-tiles-renderer/plugins";
import { DRACOLoader } from "three/examples/jsm/loaders/DRACOLoader.js";
import { KTX2Loader } from "three/examples/jsm/loaders/KTX2Loader.js";
import { MeshoptDecoder } from "three/examples/jsm/libs/meshopt_decoder.module.js";

const q = new URLSearchParams(location.search);
const lib = q.get("lib");
const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
renderer.setSize(innerWidth, innerHeight);
renderer.setClearColor(0x000000, 1);
document.body.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.add(new THREE.AmbientLight(0xffffff, 1.2));
const sun = new THREE.DirectionalLight(0xffffff, 2);
sun.position.set(1, 2, 1.5);
scene.add(sun);
const camera = new THREE.PerspectiveCamera(45, innerWidth / innerHeight, 0.05, 1e6);

const tiles = new TilesRenderer(q.get("tileset"));
tiles.registerPlugin(
  new GLTFExtensionsPlugin({
    metadata: true,
    dracoLoader: new DRACOLoader().setDecoderPath(`${lib}/three/examples/jsm/libs/draco/`),
    ktxLoader: new KTX2Loader().setTranscoderPath(`${lib}/three/examples/jsm/libs/basis/`).detectSupport(renderer),
    meshoptDecoder: MeshoptDecoder,
  }),
);
tiles.registerPlugin(new ReorientationPlugin({ up: "+y", recenter: true }));
tiles.errorTarget = Number(q.get("sse") || 1); // refine to the leaves of a model framed whole
tiles.setCamera(camera);
tiles.setResolutionFromRenderer(camera, renderer);
scene.add(tiles.group);

const state = { rootLoaded: false, framed: false, models: 0, errors: [], tiles: {}, frames: 0, loadEnds: 0 };
const copiesOf = (obj) => {
  let copies = 0;
  let instanced = 0;
  obj.traverse((o) => {
    if (!o.isMesh) return;
    if (o.isInstancedMesh) {
      copies += o.count;
      instanced++;
    } else copies += 1;
  });
  return { copies, instanced };
};
tiles.addEventListener("load-model", ({ scene: s, tile }) => {
  state.models++;
  const uri = tile.content?.uri || "";
  state.tiles[uri.startsWith("data:") ? "data:" : uri] = copiesOf(s);
});
tiles.addEventListener("load-error", ({ tile, error, url }) =>
  state.errors.push(`${tile?.content?.uri?.slice(0, 80) ?? url ?? "tileset"}: ${String(error?.message || error).slice(0, 300)}`),
);
tiles.addEventListener("tiles-load-end", () => state.loadEnds++);

function frame() {
  const sphere = new THREE.Sphere();
  if (!state.framed && tiles.root && tiles.getBoundingSphere(sphere) && sphere.radius > 0) {
    // The root is in: frame its bounding sphere from the south-east, above.
    tiles.group.updateMatrixWorld(true);
    sphere.applyMatrix4(tiles.group.matrixWorld);
    const r = sphere.radius;
    camera.position.copy(sphere.center).add(new THREE.Vector3(0.9, 0.8, 1.1).normalize().multiplyScalar(r * 2.2));
    camera.near = r / 100;
    camera.far = r * 20;
    camera.updateProjectionMatrix();
    camera.lookAt(sphere.center);
    state.framed = true;
  }
  camera.updateMatrixWorld();
  tiles.update();
  renderer.render(scene, camera);
  state.frames++;
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);

/** The feature rows (property table data) at a hit, through the plugin's MeshFeatures API. */
function rowsAt(hit) {
  const { meshFeatures, structuralMetadata } = hit.object.userData;
  if (!meshFeatures || !structuralMetadata) return null;
  const geo = hit.object.geometry;
  const tri = new THREE.Triangle();
  tri.setFromAttributeAndIndices(geo.attributes.position, hit.face.a, hit.face.b, hit.face.c);
  const m = hit.object.matrixWorld.clone();
  if (hit.instanceId !== undefined) {
    const im = new THREE.Matrix4();
    hit.object.getMatrixAt(hit.instanceId, im);
    m.multiply(im);
  }
  tri.a.applyMatrix4(m);
  tri.b.applyMatrix4(m);
  tri.c.applyMatrix4(m);
  const bary = tri.getBarycoord(hit.point, new THREE.Vector3());
  const features = meshFeatures.getFeatures(hit.faceIndex, bary);
  const tables = meshFeatures.getFeatureInfo().map((f) => f.propertyTable);
  return { features, rows: structuralMetadata.getPropertyTableData(tables, features) };
}

const raycaster = new THREE.Raycaster();
window.client = {
  state,
  stats: () => ({ ...tiles.stats }),
  busy: () => tiles.stats.downloading + tiles.stats.parsing + (tiles.stats.queued || 0),
  visibleCopies: () => copiesOf(tiles.group),
  /** Metadata under the first pixel of a grid (from the centre out) that hits the model. */
  pick() {
    const pts = [[0, 0]];
    for (let k = 1; k <= 6; k++) for (const [x, y] of [[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [-1, -1], [1, -1], [-1, 1]]) pts.push([(x * k) / 8, (y * k) / 8]);
    for (const [x, y] of pts) {
      raycaster.setFromCamera(new THREE.Vector2(x, y), camera);
      const hit = raycaster.intersectObject(tiles.group, true)[0];
      if (!hit) continue;
      const r = rowsAt(hit);
      return { hit: true, at: [x, y], object: hit.object.type, ...(r || { rows: null }) };
    }
    return { hit: false };
  },
  /**
   * EXT_instance_features: each copy of an instanced mesh has its own feature (the
   * _FEATURE_ID_0 instance attribute GLTFLoader keeps). Picks two copies with different
   * feature ids and says whether the plugin's API gives them different rows ("distinct", the
   * right answer) or the same one ("same": the copies are not told apart).
   */
  instancePick() {
    // Instanced meshes whose copies carry different feature ids (EXT_instance_features).
    const candidates = [];
    tiles.group.traverse((o) => {
      if (!o.isInstancedMesh || !o.visible) return;
      const name = Object.keys(o.geometry.attributes).find((n) => /^_feature_id_0$/i.test(n));
      if (!name) return;
      const a = o.geometry.attributes[name];
      for (let i = 1; i < o.count; i++) if (a.getX(i) !== a.getX(0)) return candidates.push([o, [0, i], [a.getX(0), a.getX(i)]]);
    });
    if (!candidates.length) return { found: false };
    // A ray from the camera to the centroid of one of the first triangles of each copy, against
    // that mesh alone: the hit on that copy.
    const hitCopy = (mesh, inst) => {
      const im = new THREE.Matrix4();
      mesh.getMatrixAt(inst, im);
      const m = mesh.matrixWorld.clone().multiply(im);
      const pos = mesh.geometry.attributes.position;
      const index = mesh.geometry.index;
      const tris = Math.min(20, (index ? index.count : pos.count) / 3);
      for (let t = 0; t < tris; t++) {
        const c = new THREE.Vector3();
        for (let k = 0; k < 3; k++) c.add(new THREE.Vector3().fromBufferAttribute(pos, index ? index.getX(3 * t + k) : 3 * t + k).divideScalar(3));
        c.applyMatrix4(m);
        raycaster.set(camera.position, c.clone().sub(camera.position).normalize());
        const hit = raycaster.intersectObject(mesh, false).find((h) => h.instanceId === inst);
        if (hit) return hit;
      }
      return null;
    };
    for (const [mesh, insts, fids] of candidates) {
      const hits = insts.map((i) => hitCopy(mesh, i));
      if (hits.some((h) => !h)) continue;
      const rows = hits.map((h) => {
        const r = rowsAt(h);
        return r ? JSON.stringify(r.rows) : null;
      });
      return {
        found: true,
        hitBoth: true,
        instanceFeatureIds: fids,
        rows,
        result: rows[0] === null ? "none" : rows[0] === rows[1] ? "same" : "distinct",
      };
    }
    return { found: true, hitBoth: false, candidates: candidates.length };
  },
};
