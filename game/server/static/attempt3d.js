// The attempt page's 3-D replay (chainsim records server): the pack's anatomy see-through, the
// trainee's landmarks and the ideal ones, the ideal path, the needle moving over the attempt's time
// with play/pause and a scrubber, the contacts where they happened, and the X-ray images the trainee
// took (each one seeks the replay to its moment). Data: /attempts/ID/replay.json (the server's replay
// of the recording) and the pack's display meshes as binary glTF. three.js is served by this site.
import * as THREE from 'three';
import { OrbitControls } from '/static/vendor/three/examples/jsm/controls/OrbitControls.js';
import { GLTFLoader } from '/static/vendor/three/examples/jsm/loaders/GLTFLoader.js';

const box = document.getElementById('replay3d');
const status = document.getElementById('replay-status');
const scrub = document.getElementById('scrubber');
const playBtn = document.getElementById('play');
const clock = document.getElementById('replay-time');
const gallery = document.getElementById('xrays');

const ORANGE = 0xe07b00, GREEN = 0x1f9d3a, RED = 0xd01010, BG = 0x1d2330;

function plural(n, word) { return `${n} ${word}${n === 1 ? '' : 's'}`; }
function say(text) { status.textContent = text; }

async function main() {
  const resp = await fetch(box.dataset.replay, { credentials: 'same-origin' });
  if (!resp.ok) {
    let msg = resp.statusText;
    try { msg = (await resp.text()).match(/<p class="error">([^<]*)/)?.[1] || msg; } catch (e) { /* keep */ }
    say('No 3-D replay: ' + msg);
    box.classList.add('empty');
    return;
  }
  const track = await resp.json();
  const canvas = document.createElement('canvas');
  canvas.id = 'replay-canvas';
  box.prepend(canvas);
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
  renderer.setClearColor(BG);
  const scene = new THREE.Scene();
  scene.add(new THREE.HemisphereLight(0xffffff, 0x445566, 2.2));
  const sun = new THREE.DirectionalLight(0xffffff, 1.5);
  sun.position.set(300, 400, 500);
  scene.add(sun);
  const camera = new THREE.PerspectiveCamera(35, 1, 1, 5000);
  camera.up.set(0, 0, 1); // the packs' anatomy is z-up (mm)
  const controls = new OrbitControls(camera, canvas);

  // anatomy: the outermost mesh (largest) faint, the rest half see-through, so the needle shows inside
  const gltf = await new GLTFLoader().loadAsync(track.mesh);
  const meshes = [];
  gltf.scene.traverse((o) => { if (o.isMesh) meshes.push(o); });
  const size = (o) => new THREE.Box3().setFromObject(o).getSize(new THREE.Vector3()).length();
  const outer = meshes.reduce((a, b) => (size(b) > size(a) ? b : a), meshes[0]);
  for (const m of meshes) {
    const mat = m.material;
    mat.transparent = true;
    mat.opacity = m === outer ? 0.14 : 0.32;
    mat.depthWrite = false;
    mat.side = THREE.DoubleSide;
    m.renderOrder = m === outer ? 2 : 1;
  }
  scene.add(gltf.scene);
  const bounds = new THREE.Box3().setFromObject(gltf.scene);
  const centre = bounds.getCenter(new THREE.Vector3());
  const radius = bounds.getSize(new THREE.Vector3()).length() / 2 || 100;

  const dot = (p, color, r) => {
    const s = new THREE.Mesh(new THREE.SphereGeometry(r, 16, 12), new THREE.MeshBasicMaterial({ color, depthTest: false }));
    s.position.set(...p);
    s.renderOrder = 7;
    scene.add(s);
    return s;
  };
  const line = (pts, color) => {
    const g = new THREE.BufferGeometry().setFromPoints(pts.map((p) => new THREE.Vector3(...p)));
    const l = new THREE.Line(g, new THREE.LineBasicMaterial({ color, depthTest: false }));
    l.renderOrder = 4;
    scene.add(l);
    return l;
  };
  track.landmarks.forEach((p) => p && dot(p, ORANGE, 2.2));
  // the ideal places as green rings around the trainee's dots, so both show where they coincide
  track.ideal_landmarks.forEach((p) => {
    if (!p) return;
    const ring = new THREE.Mesh(new THREE.SphereGeometry(3.6, 12, 8),
      new THREE.MeshBasicMaterial({ color: GREEN, wireframe: true, depthTest: false }));
    ring.position.set(...p);
    ring.renderOrder = 5;
    scene.add(ring);
  });
  if (track.ideal_path) line(track.ideal_path, GREEN);
  const contacts = track.contacts.map((c) => ({ ...c, mark: c.point[0] === null ? null : dot(c.point, RED, 2.6) }));

  // the needle: a shaft from the tip back along its direction, and the tip
  const len = track.needle_length_mm || 100;
  const shaft = new THREE.Mesh(
    new THREE.CylinderGeometry(0.9, 0.9, len, 12).translate(0, -len / 2, 0),
    new THREE.MeshBasicMaterial({ color: 0x5aa9ff, depthTest: false }));
  shaft.renderOrder = 6;
  const tipMark = dot([0, 0, 0], ORANGE, 1.8);
  scene.add(shaft);
  const trail = line([[0, 0, 0], [0, 0, 0]], ORANGE);

  const frames = track.frames;
  scrub.max = String(Math.max(frames.length - 1, 0));
  scrub.disabled = frames.length < 2;
  playBtn.disabled = frames.length < 2;
  const state = { index: 0, tip: null };
  const Y = new THREE.Vector3(0, 1, 0);

  function show(i) {
    i = Math.max(0, Math.min(frames.length - 1, i | 0));
    state.index = i;
    const f = frames[i];
    const placed = f && f[1] !== null;
    shaft.visible = tipMark.visible = placed;
    if (placed) {
      const tip = new THREE.Vector3(f[1], f[2], f[3]);
      const dir = new THREE.Vector3(f[4], f[5], f[6]).normalize();
      shaft.position.copy(tip);
      shaft.quaternion.setFromUnitVectors(Y, dir);
      tipMark.position.copy(tip);
      state.tip = [f[1], f[2], f[3]];
      const pts = frames.slice(0, i + 1).filter((g) => g[1] !== null).map((g) => new THREE.Vector3(g[1], g[2], g[3]));
      trail.geometry.dispose();
      trail.geometry = new THREE.BufferGeometry().setFromPoints(pts.length > 1 ? pts : [tip, tip]);
    } else {
      state.tip = null;
    }
    const t = f ? f[0] : 0;
    for (const c of contacts) if (c.mark) c.mark.scale.setScalar(c.t <= t + 1e-6 ? 1.0 : 0.5);
    scrub.value = String(i);
    clock.textContent = `${t.toFixed(1)} s of ${track.duration_s.toFixed(1)} s`;
    for (const fig of gallery.querySelectorAll('figure')) fig.classList.toggle('now', Number(fig.dataset.t) <= t + 1e-6 && Number(fig.dataset.next) > t + 1e-6);
  }

  // the X-ray images, in the order taken; a click seeks the replay to that moment
  track.images.forEach((im, k) => {
    const fig = document.createElement('figure');
    fig.dataset.t = im.t;
    fig.dataset.next = k + 1 < track.images.length ? track.images[k + 1].t : 1e9;
    const img = document.createElement('img');
    img.src = im.url;
    img.alt = `X-ray image ${k + 1}: ${im.view} view at ${im.t.toFixed(1)} s`;
    img.width = 256;
    img.height = 256;
    const cap = document.createElement('figcaption');
    cap.textContent = `${k + 1}. ${im.view}${im.live ? ' (live)' : ''}, ${im.t.toFixed(1)} s`;
    fig.append(img, cap);
    fig.addEventListener('click', () => { pause(); show(frames.findIndex((f) => f[0] >= im.t)); });
    gallery.append(fig);
  });
  if (!track.images.length) gallery.textContent = 'No X-ray image was taken in this attempt.';

  function resize() {
    const w = box.clientWidth, h = Math.round(Math.min(Math.max(w * 0.62, 260), 560));
    renderer.setSize(w, h, false);
    canvas.style.width = w + 'px';
    canvas.style.height = h + 'px';
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
  // look from the side the needle went in (towards the first landmark), a little from above and in front
  const first = track.landmarks.find((p) => p) || frames.find((f) => f[1] !== null)?.slice(1, 4);
  const side = first ? new THREE.Vector3(...first).sub(centre).setZ(0).normalize() : new THREE.Vector3(-1, 0, 0);
  const view = side.multiplyScalar(1.0).add(new THREE.Vector3(0, 0, 0.35)).normalize();
  camera.position.copy(centre).add(view.multiplyScalar(radius * 2.0));
  controls.target.copy(centre);
  controls.update();
  resize();
  new ResizeObserver(resize).observe(box);

  let playing = false, last = 0, simT = 0;
  function pause() { playing = false; playBtn.textContent = 'Play'; }
  playBtn.addEventListener('click', () => {
    if (playing) { pause(); return; }
    if (state.index >= frames.length - 1) show(0);
    playing = true; playBtn.textContent = 'Pause';
    simT = frames[state.index][0]; last = performance.now();
  });
  scrub.addEventListener('input', () => { pause(); show(Number(scrub.value)); });
  renderer.setAnimationLoop((now) => {
    if (playing) {
      simT += (now - last) / 1000; last = now;
      let i = state.index;
      while (i < frames.length - 1 && frames[i + 1][0] <= simT) i++;
      show(i);
      if (i >= frames.length - 1) pause();
    }
    controls.update();
    renderer.render(scene, camera);
  });
  show(0);
  window.chainsimReplay = { state, show, frames: frames.length, images: track.images.length, contacts: track.contacts.length, reached: !!track.reached };
  // contacts are bone contacts, as the procedure counts them; reaching the target is said apart, it is no contact
  const reached = track.reached ? ` the needle reached the ${track.reached.role.replaceAll('_', ' ')} at ${track.reached.t.toFixed(1)} s,` : '';
  say(`Replayed from the recording: ${frames.length} needle positions, ${plural(track.contacts.length, 'bone contact')},${reached} ${plural(track.images.length, 'X-ray image')}. Drag to turn, wheel to zoom.`);
  box.dataset.ready = '1';
}

main().catch((e) => { say('No 3-D replay: ' + e.message); box.dataset.ready = 'error'; });
