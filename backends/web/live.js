// The live page of convodrive's `stream` backend: the mannequin (glTF, skinned on SMPL-X's joint
// names, with the 52 ARKit morph targets) posed by every frame that arrives on the WebSocket.
// Frames come when their sound leaves the speaker, so on the machine that plays the robot's voice
// the face moves with what you hear. The page draws the newest frame at each screen refresh.

import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

const status = document.getElementById('status');
const canvas = document.getElementById('view');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
renderer.outputColorSpace = THREE.SRGBColorSpace;

const scene = new THREE.Scene();
scene.background = new THREE.Color(0x20232a);
scene.add(new THREE.HemisphereLight(0xf0f0ff, 0x404040, 1.6));
const key = new THREE.DirectionalLight(0xffffff, 2.2);
key.position.set(0.6, 2.2, 2.0);
scene.add(key);

// Head and shoulders, facing the avatar (it faces +Z, Y up, metres).
const camera = new THREE.PerspectiveCamera(24, 1, 0.05, 20);
let target = new THREE.Vector3(0, 1.5, 0);

function resize() {
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

const bones = new Map();      // SMPL-X joint name -> THREE.Bone
const morphMeshes = [];       // meshes carrying the ARKit morph targets
let rootRest = null;          // the pelvis's rest position (translation is added to it)
let hello = null;             // joint and channel names, frame layout
let latest = null;            // the newest frame, applied at the next screen refresh
let frames = 0, shown = -1, since = performance.now(), rate = 0;

new GLTFLoader().load('./mannequin.glb', (gltf) => {
  scene.add(gltf.scene);
  gltf.scene.traverse((o) => {
    if (o.isBone) bones.set(o.name, o);
    if (o.isMesh && o.morphTargetDictionary) morphMeshes.push(o);
  });
  const pelvis = bones.get('pelvis');
  if (pelvis) rootRest = pelvis.position.clone();
  const head = bones.get('head');
  if (head) {
    gltf.scene.updateMatrixWorld(true);
    target = head.getWorldPosition(new THREE.Vector3()).add(new THREE.Vector3(0, 0.02, 0));
  }
  document.body.dataset.avatar = 'loaded';
}, undefined, (err) => {
  document.body.dataset.avatar = 'failed';
  status.textContent = 'the avatar did not load: ' + err;
});

function decode(data) {
  if (typeof data === 'string') {
    const msg = JSON.parse(data);
    if (msg.type === 'hello') { hello = msg; return null; }
    return { index: msg.i, time: msg.t, state: msg.s, translation: msg.tr, quats: msg.q, face: msg.f, vad: msg.v };
  }
  const words = new Uint32Array(data, 0, hello.header_words);
  const floats = new Float32Array(data, 4 * hello.header_words);
  const L = hello.layout;
  let at = 0;
  const take = (n) => floats.subarray(at, (at += n));
  return {
    index: words[0], time: new Float32Array(data, 4, 1)[0], state: words[2],
    translation: take(L.translation), quats: take(L.rotations), face: take(L.face), vad: take(L.vad),
  };
}

function apply(frame) {
  hello.joints.forEach((name, j) => {
    const bone = bones.get(name);
    if (bone) bone.quaternion.set(frame.quats[4 * j], frame.quats[4 * j + 1], frame.quats[4 * j + 2], frame.quats[4 * j + 3]);
  });
  if (rootRest) bones.get('pelvis').position.set(
    rootRest.x + frame.translation[0], rootRest.y + frame.translation[1], rootRest.z + frame.translation[2]);
  for (const mesh of morphMeshes) {
    hello.face.forEach((name, c) => {
      const slot = mesh.morphTargetDictionary[name];
      if (slot !== undefined) mesh.morphTargetInfluences[slot] = frame.face[c];
    });
  }
}

const STATES = ['silence', 'speaking', 'listening', 'overlap'];

function connect() {
  const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
  const ws = new WebSocket(`${scheme}://${location.host}/ws${location.search}`);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => { document.body.dataset.connected = 'true'; };
  ws.onmessage = (event) => {
    const frame = decode(event.data);
    if (!frame) return;
    latest = frame;
    frames += 1;
    document.body.dataset.frames = String(frames);
  };
  ws.onclose = () => {
    document.body.dataset.connected = 'false';
    status.textContent = 'disconnected (the run ended?) — retrying…';
    setTimeout(connect, 1000);
  };
}
connect();

// Where the face is on screen (CSS pixels: centre x, y and a radius), for tools that watch it.
function markFace() {
  const head = bones.get('head');
  if (!head) return;
  const centre = head.getWorldPosition(new THREE.Vector3()).add(new THREE.Vector3(0, 0.03, 0.08));
  const edge = centre.clone().add(new THREE.Vector3(0.11, 0, 0));
  const px = (v) => { v.project(camera); return [(v.x + 1) / 2 * canvas.clientWidth, (1 - v.y) / 2 * canvas.clientHeight]; };
  const [x, y] = px(centre.clone()), [ex] = px(edge);
  document.body.dataset.face = `${Math.round(x)},${Math.round(y)},${Math.round(Math.abs(ex - x))}`;
}

function draw(now) {
  if (latest && hello && bones.size && latest.index !== shown) {
    apply(latest);
    shown = latest.index;
    document.body.dataset.frame = String(shown);
  }
  if (now - since > 1000) {
    rate = Math.round((frames - (draw.last || 0)) * 1000 / (now - since));
    draw.last = frames;
    since = now;
    if (latest) status.textContent =
      `live · frame ${latest.index} · ${rate} frames/s · ${STATES[latest.state] || ''}`;
  }
  camera.position.set(target.x, target.y + 0.02, target.z + 1.3);
  camera.lookAt(target);
  renderer.render(scene, camera);
  markFace();
  requestAnimationFrame(draw);
}
requestAnimationFrame(draw);
