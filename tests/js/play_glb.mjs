// three.js plays a glb's first animation and writes the skinned vertex positions at the given times, as an
// engine does: node play_glb.mjs FILE.glb '[t0, t1, ...]' OUT.json [loop]  ->  OUT.json: [[x, y, z, ...], ...]
// (glTF axes); with "loop", in a loop (LoopRepeat, as a game loops a cycle), else once.
import fs from 'node:fs';
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';

const [, , file, timesJson, outFile, mode] = process.argv;
const data = withoutImages(fs.readFileSync(file));
const loader = new GLTFLoader();
loader.parse(data, '', (gltf) => {
  let mesh = null;
  gltf.scene.traverse((o) => { if (o.isSkinnedMesh && !mesh) mesh = o; });
  if (!mesh || gltf.animations.length === 0) { console.error('no skinned mesh or no animation'); process.exit(3); }
  const mixer = new THREE.AnimationMixer(gltf.scene);
  const action = mixer.clipAction(gltf.animations[0]);
  if (mode === 'loop') {
    action.setLoop(THREE.LoopRepeat, Infinity);   // as an engine loops a cycle: past the end, from the start again
  } else {
    action.setLoop(THREE.LoopOnce, 1);      // the last key is the last frame, not the first again
    action.clampWhenFinished = true;
  }
  action.play();
  const out = [];
  const v = new THREE.Vector3();
  for (const t of JSON.parse(timesJson)) {
    mixer.setTime(t);
    gltf.scene.updateMatrixWorld(true);
    mesh.skeleton.update();
    const n = mesh.geometry.attributes.position.count;
    const frame = new Array(3 * n);
    for (let i = 0; i < n; i++) {
      mesh.getVertexPosition(i, v);
      v.applyMatrix4(mesh.matrixWorld);
      frame[3 * i] = v.x; frame[3 * i + 1] = v.y; frame[3 * i + 2] = v.z;
    }
    out.push(frame);
  }
  fs.writeFileSync(outFile, JSON.stringify({ bones: mesh.skeleton.bones.length, duration: gltf.animations[0].duration, frames: out }));
}, (e) => { console.error(String(e)); process.exit(2); });

// Node has no image decoder (three.js reaches for `self` and `document`): the GLB is parsed without its images,
// which skinning does not read; the rest of the file is as written.
function withoutImages(buf) {
  const len = buf.readUInt32LE(12);
  const doc = JSON.parse(buf.subarray(20, 20 + len).toString('utf8'));
  delete doc.images; delete doc.textures; delete doc.samplers;
  for (const m of doc.materials || []) {
    for (const k of ['normalTexture', 'occlusionTexture', 'emissiveTexture']) delete m[k];
    if (m.pbrMetallicRoughness) { delete m.pbrMetallicRoughness.baseColorTexture; delete m.pbrMetallicRoughness.metallicRoughnessTexture; }
  }
  let json = Buffer.from(JSON.stringify(doc), 'utf8');
  json = Buffer.concat([json, Buffer.alloc((4 - (json.length % 4)) % 4, 0x20)]);
  const bin = buf.subarray(20 + len);
  const head = Buffer.alloc(20);
  head.writeUInt32LE(0x46546C67, 0); head.writeUInt32LE(2, 4); head.writeUInt32LE(20 + json.length + bin.length, 8);
  head.writeUInt32LE(json.length, 12); head.writeUInt32LE(0x4E4F534A, 16);
  const out = Buffer.concat([head, json, bin]);
  return out.buffer.slice(out.byteOffset, out.byteOffset + out.byteLength);
}
