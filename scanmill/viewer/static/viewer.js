// scanmill plan viewer (issue 20): the scan coloured by area, the set-ups' tool axes and machine angles,
// the integrated and unmachined points, every area's finishing and roughing paths, the verification's
// deviation map. Data: viewer.json (index) + viewer.points.bin + viewer.paths.bin (planning/report/viewer_data.py),
// fetched from data-artifacts with the API key as an Authorization: Bearer header (never in a URL).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const state = window.scanmillViewer = {
  ready: false, pathsReady: false, errors: [], firstFrameMs: null, pathsMs: null, bytes: 0, index: null, frames: 0,
};
window.addEventListener('error', (e) => state.errors.push(String(e.message || e)));
window.addEventListener('unhandledrejection', (e) => state.errors.push(String(e.reason)));

const base = document.body.dataset.artifacts;
const KEY_SLOT = 'scanmill-key:' + location.origin;
const $ = (id) => document.getElementById(id);

// ---------------------------------------------------------------------------------------------- key
function takeKeyFromFragment() {
  // `scanmill view` prints an address with #key=...: a fragment never reaches the server or its logs
  const m = location.hash.match(/(?:^#|&)key=([^&]+)/);
  if (m) {
    sessionStorage.setItem(KEY_SLOT, decodeURIComponent(m[1]));
    history.replaceState(null, '', location.pathname + location.search);
  }
}

class HttpError extends Error {
  constructor(status, detail) { super(detail); this.status = status; }
}

async function get(name, as) {
  const key = sessionStorage.getItem(KEY_SLOT);
  const headers = key ? { Authorization: 'Bearer ' + key } : {};
  const r = await fetch(base + name, { headers, cache: 'no-store' });
  if (!r.ok) {
    let detail = r.statusText;
    try { detail = (await r.json()).detail || detail; } catch (_) { /* not a problem document */ }
    throw new HttpError(r.status, detail);
  }
  const body = as === 'json' ? await r.json() : await r.arrayBuffer();
  if (as !== 'json') state.bytes += body.byteLength;
  return body;
}

function setStatus(text, isError) {
  $('status').textContent = text;
  $('status').classList.toggle('error', !!isError);
}

function askForKey(message) {
  setStatus(message, true);
  $('verdict').textContent = 'locked';
  const form = $('keyform');
  form.hidden = false;
  $('key').focus();
  return new Promise((resolve) => {
    form.onsubmit = (ev) => {
      ev.preventDefault();
      sessionStorage.setItem(KEY_SLOT, $('key').value.trim());
      $('key').value = '';
      form.hidden = true;
      resolve();
    };
  });
}

async function loadIndex() {
  for (;;) {
    try {
      return await get('viewer.json', 'json');
    } catch (e) {
      if (!(e instanceof HttpError)) throw e;
      if (e.status === 401) {
        const had = sessionStorage.getItem(KEY_SLOT);
        sessionStorage.removeItem(KEY_SLOT);
        await askForKey(had ? 'The key was refused: ' + e.message : 'This job needs its API key.');
        continue;
      }
      const why = { 403: 'Not allowed: ', 404: 'No such plan or job (or not yours): ',
                    409: 'The job has not finished yet: ' }[e.status] || ('HTTP ' + e.status + ': ');
      throw new Error(why + e.message);
    }
  }
}

// ------------------------------------------------------------------------------------------ arrays
function view(buffers, entry) {
  const buf = buffers[entry.file];
  const n = entry.shape.reduce((a, b) => a * b, 1);
  switch (entry.dtype) {
    case '<u2': return new Uint16Array(buf, entry.offset, n);
    case '<i2': return new Int16Array(buf, entry.offset, n);
    case '|u1': return new Uint8Array(buf, entry.offset, n);
    case '|i1': return new Int8Array(buf, entry.offset, n);
    default: throw new Error('unknown array type ' + entry.dtype);
  }
}

// quantised uint16 positions: the GPU normalises them to [0, 1]; the object's scale and position map
// them back to millimetres (planning/report/viewer_data.py quantise)
function placeQuantised(object, boxMin, boxMax) {
  object.scale.set(boxMax[0] - boxMin[0], boxMax[1] - boxMin[1], boxMax[2] - boxMin[2]);
  object.position.set(boxMin[0], boxMin[1], boxMin[2]);
}

// ------------------------------------------------------------------------------------------- scene
THREE.ColorManagement.enabled = false;          // the palette's bytes are the pixels' bytes
const canvas = $('canvas');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
renderer.setPixelRatio(1);
renderer.setClearColor(0xf4f4f2);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(35, 1, 0.1, 100000);
camera.up.set(0, 0, 1);
const controls = new OrbitControls(camera, canvas);
controls.addEventListener('change', () => requestRender());
const axesGroup = new THREE.Group();
scene.add(axesGroup);
const labels = [];
let pending = false;

function resize() {
  const w = canvas.clientWidth || 800, h = canvas.clientHeight || 600;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}

function requestRender() {
  if (pending) return;
  pending = true;
  requestAnimationFrame(() => { pending = false; renderNow(); });
}

function renderNow() {
  renderer.render(scene, camera);
  state.frames += 1;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  for (const l of labels) {
    const p = l.at.clone().project(camera);
    l.el.style.left = ((p.x + 1) / 2 * w) + 'px';
    l.el.style.top = ((1 - p.y) / 2 * h) + 'px';
    l.el.style.display = (p.z < 1 && axesGroup.visible) ? '' : 'none';
  }
}
window.addEventListener('resize', () => { resize(); requestRender(); });

// ------------------------------------------------------------------------------------------ points
let cloud = null;

function colourPoints(idx, arrays) {
  const mode = document.querySelector('input[name=colour]:checked').value;
  const showUnmachined = $('show-unmachined').checked, darken = $('show-integrated').checked;
  const { label, flags, deviation } = arrays;
  const n = label.length;
  const rgb = cloud.geometry.attributes.color.array;
  const pal = idx.colors.areas, unc = idx.colors.uncovered;
  if (mode === 'deviation' && deviation) {
    const lut = deviationLut(idx.deviation.limit_mm);
    for (let i = 0; i < n; i++) {
      const j = lutIndex(deviation[i] / 1000, idx.deviation.limit_mm) * 3;
      rgb[3 * i] = lut[j]; rgb[3 * i + 1] = lut[j + 1]; rgb[3 * i + 2] = lut[j + 2];
    }
  } else {
    for (let i = 0; i < n; i++) {
      const c = label[i] === 255 ? unc : pal[label[i]];
      let f = 1;
      if (darken && (flags[i] & 1)) f = 0.55;
      if (showUnmachined && (flags[i] & 2)) {
        rgb[3 * i] = 230; rgb[3 * i + 1] = 20; rgb[3 * i + 2] = 20; continue;
      }
      rgb[3 * i] = c[0] * f; rgb[3 * i + 1] = c[1] * f; rgb[3 * i + 2] = c[2] * f;
    }
  }
  cloud.geometry.attributes.color.needsUpdate = true;
  $('colourbar').hidden = mode !== 'deviation';
  requestRender();
}

// deviation colours: blue below -limit (cut too deep), green within +-limit, yellow to red above
// (material left) up to 10 x limit; 256 steps over [-10 limit, 10 limit]
const DEV_STEPS = 256;
function lutIndex(d, limit) {
  const t = Math.max(-1, Math.min(1, d / (10 * limit)));
  return Math.round((t + 1) / 2 * (DEV_STEPS - 1));
}
let lutCache = null;
function deviationLut(limit) {
  if (lutCache && lutCache.limit === limit) return lutCache.lut;
  const lut = new Uint8Array(DEV_STEPS * 3);
  for (let s = 0; s < DEV_STEPS; s++) {
    const d = (s / (DEV_STEPS - 1) * 2 - 1) * 10 * limit;
    let c;
    if (Math.abs(d) <= limit) c = [40, 170, 60];
    else if (d < 0) { const t = Math.min(1, (-d - limit) / (9 * limit)); c = [30, 120 - 90 * t, 230]; }
    else { const t = Math.min(1, (d - limit) / (9 * limit)); c = [240, 220 - 200 * t, 30]; }
    lut.set(c.map(Math.round), 3 * s);
  }
  lutCache = { limit, lut };
  return lut;
}

function drawColourBar(idx) {
  const limit = idx.deviation.limit_mm;
  const lut = deviationLut(limit);
  const cv = $('colourbar-canvas'), g = cv.getContext('2d');
  for (let x = 0; x < cv.width; x++) {
    const j = Math.round(x / (cv.width - 1) * (DEV_STEPS - 1)) * 3;
    g.fillStyle = `rgb(${lut[j]},${lut[j + 1]},${lut[j + 2]})`;
    g.fillRect(x, 0, 1, cv.height);
  }
  const ticks = [-10, -1, 0, 1, 10].map((m) => (m * limit).toFixed(3));
  ticks[0] = '&le;' + ticks[0]; ticks[4] = '&ge;' + ticks[4];
  $('colourbar-ticks').innerHTML = ticks.map((t) => `<span>${t}</span>`).join('');
}

// the scan's points: flat colours, or shaded by a headlight (the light comes from the eye: a point
// facing the viewer keeps its colour exactly, one seen edge-on falls to 35 %) so the shape reads;
// normals arrive as int8 and the GPU normalises them
const POINTS_VERTEX = `
  uniform float pointSize;
  uniform bool shade;
  attribute vec3 normal8;
  varying vec3 vColour;
  void main() {
    vec4 mv = modelViewMatrix * vec4(position, 1.0);
    gl_Position = projectionMatrix * mv;
    gl_PointSize = pointSize;
    float f = 1.0;
    if (shade) {
      vec3 n = mat3(viewMatrix) * normal8;
      float len = length(n);
      f = len > 0.0 ? 0.35 + 0.65 * abs(dot(n / len, normalize(-mv.xyz))) : 1.0;
    }
    vColour = color * f;
  }`;
const POINTS_FRAGMENT = `
  varying vec3 vColour;
  void main() { gl_FragColor = vec4(vColour, 1.0); }`;

function buildPoints(idx, buffers) {
  const a = idx.points.arrays;
  const arrays = { position: view(buffers, a.position), label: view(buffers, a.label), flags: view(buffers, a.flags),
                   deviation: a.deviation ? view(buffers, a.deviation) : null,
                   normal: a.normal ? view(buffers, a.normal) : null };
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(arrays.position, 3, true));
  g.setAttribute('color', new THREE.BufferAttribute(new Uint8Array(arrays.label.length * 3), 3, true));
  g.setAttribute('normal8', arrays.normal ? new THREE.BufferAttribute(arrays.normal, 3, true)
                                          : new THREE.BufferAttribute(new Int8Array(arrays.label.length * 3), 3, true));
  const m = new THREE.ShaderMaterial({
    uniforms: { pointSize: { value: 2 }, shade: { value: !!arrays.normal } },
    vertexShader: POINTS_VERTEX, fragmentShader: POINTS_FRAGMENT, vertexColors: true,
  });
  cloud = new THREE.Points(g, m);
  placeQuantised(cloud, idx.points.box_min_mm, idx.points.box_max_mm);
  cloud.frustumCulled = false;
  scene.add(cloud);
  colourPoints(idx, arrays);
  for (const id of ['show-unmachined', 'show-integrated']) $(id).onchange = () => colourPoints(idx, arrays);
  for (const r of document.querySelectorAll('input[name=colour]')) r.onchange = () => colourPoints(idx, arrays);
  $('point-size').oninput = (e) => { m.uniforms.pointSize.value = Number(e.target.value); requestRender(); };
  $('shading').disabled = !arrays.normal;
  $('shading').checked = !!arrays.normal;
  $('shading').onchange = (e) => { m.uniforms.shade.value = e.target.checked; requestRender(); };
  if (arrays.deviation && idx.deviation) { $('colour-deviation').disabled = false; drawColourBar(idx); }
}

// the camera sees the whole scan and every tool axis with its label: a sphere about the box centre
// holding the box and the arrows (0.45 x the diagonal, label beyond), at the distance that fits it in
// the narrower field of view
function frameCamera(idx) {
  const lo = new THREE.Vector3(...idx.points.box_min_mm), hi = new THREE.Vector3(...idx.points.box_max_mm);
  const centre = lo.clone().add(hi).multiplyScalar(0.5);
  const size = hi.clone().sub(lo).length();
  const radius = idx.setups.length ? 0.45 * size * 1.25 : 0.5 * size;
  const vfov = THREE.MathUtils.degToRad(camera.fov) / 2;
  const hfov = Math.atan(Math.tan(vfov) * camera.aspect);
  const dist = radius / Math.sin(Math.min(vfov, hfov));
  controls.target.copy(centre);
  camera.position.copy(centre).add(new THREE.Vector3(1, -1.3, 0.9).normalize().multiplyScalar(dist));
  camera.near = size / 1000; camera.far = dist + 10 * size;
  camera.updateProjectionMatrix();
  controls.update();
  return { centre, size };
}

function buildAxes(idx, centre, size) {
  const rot = idx.rotary_axes || ['tilt', 'rotary'];
  for (const s of idx.setups) {
    const dir = new THREE.Vector3(...s.tool_axis).normalize();
    const colour = new THREE.Color(s.color[0] / 255, s.color[1] / 255, s.color[2] / 255);
    const len = 0.45 * size;
    axesGroup.add(new THREE.ArrowHelper(dir, centre, len, colour, 0.08 * len, 0.04 * len));
    const el = document.createElement('span');
    const angles = rot.map((r) => `${r} ${fmt(s.rotary_deg[r], 1)}°`).join(' ');
    el.textContent = `${s.id}: ${angles}`;
    el.style.color = `rgb(${s.color.join(',')})`;
    $('labels').appendChild(el);
    labels.push({ el, at: centre.clone().add(dir.clone().multiplyScalar(len * 1.2)) });
  }
  $('show-axes').onchange = (e) => { axesGroup.visible = e.target.checked; requestRender(); };
}

const fmt = (v, d) => (v === null || v === undefined) ? '' : Number(v).toFixed(d);

function fillTable(idx) {
  const rot = idx.rotary_axes || ['tilt', 'rotary'];
  $('rot0').textContent = rot[0] + ' (deg)';
  $('rot1').textContent = rot[1] + ' (deg)';
  const body = document.querySelector('#setups tbody');
  for (const s of idx.setups) {
    const tr = document.createElement('tr');
    tr.dataset.setup = s.id;
    tr.innerHTML = `<td><span class="swatch" style="background:rgb(${s.color.join(',')})"></span>${s.id}</td>` +
      `<td class="rot0">${fmt(s.rotary_deg[rot[0]], 3)}</td><td class="rot1">${fmt(s.rotary_deg[rot[1]], 3)}</td>` +
      `<td>${fmt(s.phi_deg, 1)}</td><td>${fmt(s.theta_deg, 1)}</td>` +
      `<td>${s.n_input_points.toLocaleString('en')}</td><td>${s.finishing_mode || ''}</td>` +
      `<td><input type="checkbox" class="toggle-scan" checked title="scan points of this area"></td>` +
      `<td><input type="checkbox" class="toggle-path" data-op="finishing" disabled title="finishing path"></td>` +
      `<td><input type="checkbox" class="toggle-path" data-op="roughing" disabled title="roughing path"></td>`;
    body.appendChild(tr);
  }
}

// per-area scan toggles: the points of the areas left on are drawn through an index (all points
// when every area is on)
function wireScanToggles(idx) {
  const label = view(state.buffers, idx.points.arrays.label);
  for (const cb of document.querySelectorAll('.toggle-scan')) {
    cb.onchange = () => {
      const hidden = new Set([...document.querySelectorAll('.toggle-scan')]
        .filter((c) => !c.checked).map((c) => Number(c.closest('tr').dataset.setup)));
      let keep = null;
      if (hidden.size) {
        const k = new Uint32Array(label.length);
        let m = 0;
        for (let i = 0; i < label.length; i++) if (!hidden.has(label[i])) k[m++] = i;
        keep = new THREE.BufferAttribute(k.slice(0, m), 1);
      }
      cloud.geometry.setIndex(keep);
      requestRender();
    };
  }
}

// ------------------------------------------------------------------------------------------- paths
function buildPaths(idx, buffers) {
  const box = idx.paths.box;
  for (const item of idx.paths.items) {
    const verts = view(buffers, item.vertices), use = view(buffers, item.use);
    const attr = new THREE.BufferAttribute(verts, 3, true);     // shared by the cut and rapid geometries
    let nCut = 0;
    for (let i = 1; i < use.length; i++) if (use[i] !== 0) nCut++;
    const cuts = new Uint32Array(2 * nCut), rapids = new Uint32Array(2 * (use.length - 1 - nCut));
    for (let i = 1, c = 0, r = 0; i < use.length; i++) {
      if (use[i] !== 0) { cuts[c++] = i - 1; cuts[c++] = i; } else { rapids[r++] = i - 1; rapids[r++] = i; }
    }
    const s = idx.setups.find((x) => x.id === item.area);
    const c = s ? s.color : [0, 0, 0];
    const shade = item.operation === 'roughing' ? 0.5 : 1.0;
    const colour = new THREE.Color(c[0] * shade / 255, c[1] * shade / 255, c[2] * shade / 255);
    const gc = new THREE.BufferGeometry(), gr = new THREE.BufferGeometry();
    gc.setAttribute('position', attr); gc.setIndex(new THREE.BufferAttribute(cuts, 1));
    gr.setAttribute('position', attr); gr.setIndex(new THREE.BufferAttribute(rapids, 1));
    const cutLines = new THREE.LineSegments(gc, new THREE.LineBasicMaterial({ color: colour }));
    const rapidLines = new THREE.LineSegments(gr, new THREE.LineBasicMaterial({ color: 0x9e9e9e }));
    for (const o of [cutLines, rapidLines]) { placeQuantised(o, box.min_mm, box.max_mm); o.visible = false; o.frustumCulled = false; scene.add(o); }
    const cb = document.querySelector(`tr[data-setup="${item.area}"] .toggle-path[data-op="${item.operation}"]`);
    if (cb) {
      cb.disabled = false;
      const apply = () => { cutLines.visible = cb.checked; rapidLines.visible = cb.checked && $('show-rapids').checked; requestRender(); };
      cb.onchange = apply;
      $('show-rapids').addEventListener('change', apply);
    }
  }
}

// ---------------------------------------------------------------------------------------- offences
// the verification's worst offences: magenta markers drawn over everything, and a table naming the
// program line of each (what to look at before running anything)
const OFFENCE_COLOUR = [255, 0, 255];
function buildOffences(idx) {
  const list = idx.offences || [];
  if (!list.length) return;
  const pos = new Float32Array(list.length * 3);
  list.forEach((o, i) => pos.set(o.position_mm, 3 * i));
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
  const m = new THREE.PointsMaterial({ size: 12, sizeAttenuation: false, depthTest: false,
    color: new THREE.Color(OFFENCE_COLOUR[0] / 255, OFFENCE_COLOUR[1] / 255, OFFENCE_COLOUR[2] / 255) });
  const markers = new THREE.Points(g, m);
  markers.renderOrder = 10;
  scene.add(markers);
  const body = document.querySelector('#offences tbody');
  for (const o of list) {
    const tr = document.createElement('tr');
    for (const v of [o.kind.replaceAll('_', ' '), o.program, o.line, fmt(o.amount, 3), o.detail || '']) {
      const td = document.createElement('td');
      td.textContent = String(v);
      tr.appendChild(td);
    }
    body.appendChild(tr);
  }
  $('offences').hidden = false;
}

// -------------------------------------------------------------------------------------------- main
async function main() {
  takeKeyFromFragment();
  resize();
  const idx = await loadIndex();
  state.index = idx;
  $('title').textContent = (idx.name || 'plan') + ' — scanmill';
  const v = idx.verification;
  $('verdict').textContent = v ? 'verification ' + v.status : 'not verified';
  $('verdict').className = 'badge ' + (v ? v.status : '');
  $('message').textContent = idx.message + (v ? ' — ' + v.message : '');
  fillTable(idx);
  setStatus('Loading ' + idx.points.n_shown.toLocaleString('en') + ' points...');
  const buffers = { 'viewer.points.bin': await get('viewer.points.bin') };
  state.buffers = buffers;
  buildPoints(idx, buffers);
  const { centre, size } = frameCamera(idx);
  buildAxes(idx, centre, size);
  buildOffences(idx);
  wireScanToggles(idx);
  renderNow();
  await new Promise((r) => requestAnimationFrame(() => r()));   // the frame has reached the screen
  state.firstFrameMs = performance.now();     // since the navigation started (the page's time origin)
  state.ready = true;
  const shown = idx.points.n_shown, total = idx.points.n_total;
  $('counts').textContent = `${shown.toLocaleString('en')} of ${total.toLocaleString('en')} points shown; ` +
    `${idx.points.n_integrated.toLocaleString('en')} integrated, ${idx.points.n_unmachined.toLocaleString('en')} unmachined`;
  setStatus('Drawn in ' + (state.firstFrameMs / 1000).toFixed(2) + ' s; loading the tool paths...');
  if (idx.paths.items.length) {
    buffers['viewer.paths.bin'] = await get('viewer.paths.bin');
    buildPaths(idx, buffers);
  }
  state.pathsMs = performance.now();
  state.pathsReady = true;
  setStatus('Drawn in ' + (state.firstFrameMs / 1000).toFixed(2) + ' s; ' +
            (state.bytes / 1e6).toFixed(1) + ' MB of arrays. Drag to orbit, wheel to zoom, right-drag to pan.');
}

main().catch((e) => {
  setStatus(String(e.message || e), true);
  $('verdict').textContent = 'error';
  state.error = String(e.message || e);
});
