// scanmill plan viewer (issue 20, issue 34): the scan coloured by area, the set-ups' tool axes and machine
// angles in machining order with their times and point counts (plan.json figures), the integrated and
// unmachined points, every area's finishing paths (shown) and roughing paths (a toggle, translucent), the
// verification's deviation map in the colours of planning/report/deviation.py.
// Data: viewer.json (index) + viewer.points.bin + viewer.paths.bin (planning/report/viewer_data.py),
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
    for (let i = 0; i < n; i++) {
      const c = deviationColour(deviation[i]);
      rgb[3 * i] = c[0]; rgb[3 * i + 1] = c[1]; rgb[3 * i + 2] = c[2];
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

// deviation colours, the one convention of planning/report/deviation.py (DEVIATION_COLORS): green within
// the limit, a ramp to blue where material is left (d > 0), to red where cut below the scan (d < 0),
// saturated at deviation.saturation x the limit, grey where not measured. viewer.json carries the
// convention's own colours of every micrometre up to the saturation (deviation.lut, made by
// deviation_colors), so a point here has the colour it has in deviation.ply and deviation.png.
const DEV_DEFAULT_COLOURS = { within: [60, 170, 75], left: [30, 80, 220], cut: [220, 30, 30], unmeasured: [128, 128, 128] };
let devLut = null;         // { first: lut_first_um, rgb: Uint8Array (m * 3), unmeasured, colours }

function setupDeviation(idx, buffers) {
  const d = idx.deviation;
  const colours = d.colors || DEV_DEFAULT_COLOURS;
  const unmeasured = d.unmeasured_um === undefined ? -32768 : d.unmeasured_um;
  if (d.lut) {
    devLut = { first: d.lut_first_um, rgb: view(buffers, d.lut), unmeasured, colours };
    return;
  }
  // a viewer.json written before issue 34 has no table: the same convention from the names, a linear
  // ramp from a light tint to the saturated colour (close to, not exactly, deviation_colors)
  const sat = d.saturation || 10, limit = d.limit_mm, span = Math.max(1, Math.ceil(sat * limit * 1000));
  const rgb = new Uint8Array((2 * span + 1) * 3);
  for (let k = -span; k <= span; k++) {
    const mm = k / 1000;
    let c = colours.within;
    if (Math.abs(mm) > limit) {
      const a = Math.min(1, (Math.abs(mm) - limit) / (limit * (sat - 1))), t = 0.25 + 0.75 * a;
      const to = mm > 0 ? colours.left : colours.cut;
      c = to.map((v) => (1 - t) * 235 + t * v);
    }
    rgb.set(c.map(Math.round), 3 * (k + span));
  }
  devLut = { first: -span, rgb, unmeasured, colours };
}

// [r, g, b] of a deviation in micrometres (viewer.points.bin's int16)
function deviationColour(um) {
  if (um === devLut.unmeasured || !Number.isFinite(um)) return devLut.colours.unmeasured;
  const m = devLut.rgb.length / 3;
  const j = Math.max(0, Math.min(m - 1, Math.round(um) - devLut.first)) * 3;
  return [devLut.rgb[j], devLut.rgb[j + 1], devLut.rgb[j + 2]];
}
state.deviationColour = (mm) => (devLut ? deviationColour(mm === null ? NaN : mm * 1000) : null);

function drawColourBar(idx) {
  const limit = idx.deviation.limit_mm, sat = idx.deviation.saturation || 10;
  const span = -devLut.first;                  // micrometres, the saturation
  const cv = $('colourbar-canvas'), g = cv.getContext('2d');
  for (let x = 0; x < cv.width; x++) {
    const c = deviationColour(Math.round((x / (cv.width - 1) * 2 - 1) * span));
    g.fillStyle = `rgb(${c[0]},${c[1]},${c[2]})`;
    g.fillRect(x, 0, 1, cv.height);
  }
  // ticks at their places on the (linear) bar; the green band, +-limit, is named in the legend
  const ticks = [-sat, -sat / 2, 0, sat / 2, sat].map((m) => (m * limit).toFixed(3));
  ticks[0] = '&le;' + ticks[0]; ticks[4] = '&ge;' + ticks[4];
  $('colourbar-ticks').innerHTML = ticks.map((t) => `<span>${t}</span>`).join('');
  const sw = (c) => `<span class="swatch" style="background:rgb(${c.join(',')})"></span>`;
  const col = devLut.colours;
  $('colourbar-legend').innerHTML =
    `Deviation of the scan from the simulated result, mm: ${sw(col.within)}green within &plusmn;${limit.toFixed(3)} ` +
    `(the finishing limit); ${sw(col.left)}blue: material left (+); ${sw(col.cut)}red: cut below the scan (&minus;); ` +
    `saturated at ${sat} &times; the limit; ${sw(col.unmeasured)}grey: not measured. ` +
    'The same colours as deviation.ply and deviation.png.';
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
  for (const r of document.querySelectorAll('input[name=colour]')) {
    r.onchange = () => { pathsForColour(); colourPoints(idx, arrays); };
  }
  $('point-size').oninput = (e) => { m.uniforms.pointSize.value = Number(e.target.value); requestRender(); };
  $('shading').disabled = !arrays.normal;
  $('shading').checked = !!arrays.normal;
  $('shading').onchange = (e) => { m.uniforms.shade.value = e.target.checked; requestRender(); };
  if (arrays.deviation && idx.deviation) {
    setupDeviation(idx, buffers);
    $('colour-deviation').disabled = false;
    drawColourBar(idx);
  }
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

// Figures as the CLI summary (scanmill/summary.py) prints them, Python's rounding included (exact halves to
// even, where JavaScript's toFixed rounds them up): minutes to one decimal ('{:.1f}' of s / 60), '-' for
// none; the total as H:MM (round(s / 60)); counts with thousands commas ('{:,}'); shares as '{:.1%}'.
function pyFixed(x, d) {
  if (!Number.isFinite(x)) return String(x);
  const sign = (x < 0 || Object.is(x, -0)) ? '-' : '', a = Math.abs(x), p = 10 ** d;
  const s = a * 2 ** (d + 1);                  // an exact decimal half is odd / 2^(d+1) (exact scaling)
  if (Number.isInteger(s) && s % 2 === 1 && s < 2 ** 52) {
    const lo = Math.floor(a * p);              // exact here: a * 10^d = odd * 5^d / 2
    return sign + ((lo % 2 === 0 ? lo : lo + 1) / p).toFixed(d);
  }
  return sign + a.toFixed(d);
}
function pyRound(x) {                        // Python's round(): halves to even
  const f = Math.floor(x), diff = x - f;
  if (diff === 0.5) return f % 2 === 0 ? f : f + 1;
  return Math.round(x);
}
const figFmt = {
  minutes: (s) => (s === null || s === undefined) ? '-' : pyFixed(s / 60, 1),
  hmm: (s) => { const m = pyRound(s / 60); return `${Math.floor(m / 60)}:${String(m % 60).padStart(2, '0')}`; },
  count: (n) => (n === null || n === undefined) ? '-' : Number(n).toLocaleString('en'),
  share: (x, d = 1) => (x === null || x === undefined) ? '-' : pyFixed(x * 100, d) + '%',
};
state.format = figFmt;

// the set-ups in plan.json's machining_order (those it leaves out after them, in plan order)
function orderedSetups(idx) {
  const byId = new Map(idx.setups.map((s) => [s.id, s]));
  const order = (idx.machining_order && idx.machining_order.length) ? idx.machining_order
    : idx.setups.filter((s) => s.order !== null && s.order !== undefined).sort((a, b) => a.order - b.order).map((s) => s.id);
  const out = [], seen = new Set();
  for (const id of order) if (byId.has(id) && !seen.has(id)) { out.push(byId.get(id)); seen.add(id); }
  for (const s of idx.setups) if (!seen.has(s.id)) out.push(s);
  return out;
}

const swatch = (c) => `<span class="swatch" style="background:rgb(${c.join(',')})"></span>`;

function fillTable(idx) {
  const rot = idx.rotary_axes || ['tilt', 'rotary'];
  $('rot0').textContent = rot[0] + ' (deg)';
  $('rot1').textContent = rot[1] + ' (deg)';
  const body = document.querySelector('#setups tbody');
  orderedSetups(idx).forEach((s, k) => {
    const tr = document.createElement('tr');
    tr.dataset.setup = s.id;
    tr.innerHTML = `<td class="order">${k + 1}</td><td>${swatch(s.color)}${s.id}</td>` +
      `<td class="rot0">${fmt(s.rotary_deg[rot[0]], 3)}</td><td class="rot1">${fmt(s.rotary_deg[rot[1]], 3)}</td>` +
      `<td>${fmt(s.phi_deg, 1)}</td><td>${fmt(s.theta_deg, 1)}</td>` +
      `<td>${s.n_input_points.toLocaleString('en')}</td><td>${s.finishing_mode || ''}</td>` +
      `<td><input type="checkbox" class="toggle-scan" checked title="scan points of this area"></td>` +
      `<td><input type="checkbox" class="toggle-path" data-op="finishing" disabled checked title="finishing path"></td>` +
      `<td><input type="checkbox" class="toggle-path" data-op="semi_finishing" disabled title="semi-finishing path"></td>` +
      `<td><input type="checkbox" class="toggle-path" data-op="roughing" disabled title="roughing path"></td>`;
    body.appendChild(tr);
  });
  fillFigures(idx);
}

// plan.json's figures (issue 34), nothing recomputed: per area in machining order its roughing, semi-finishing
// (a column only where the plan has that operation, as the CLI summary), finishing and total minutes and its
// input points finished / left / unreached / not covered; the plan's totals below
function fillFigures(idx) {
  const f = idx.figures;
  if (!f) {
    $('figures-note').textContent = 'This plan has no figures (times and finished points): it was planned ' +
      'before they existed; plan it again to see them.';
    return;
  }
  const colour = new Map(idx.setups.map((s) => [s.id, s.color]));
  const body = document.querySelector('#figures tbody');
  const cells = (vals, cls) => vals.map((v, i) => `<td class="${cls[i]}">${v}</td>`).join('');
  const semi = (f.areas || []).some((a) => a.semi_finishing_time_s !== null && a.semi_finishing_time_s !== undefined);
  if (semi && !$('figures-semi')) {
    const th = document.createElement('th');
    th.id = 'figures-semi';
    th.title = 'semi-finishing, minutes (paths.semi_finishing)';
    th.textContent = 'semi';
    document.querySelector('#figures thead tr:nth-child(2) th').after(th);
    $('figures-minutes').colSpan = 4;
  }
  const withSemi = (vals, v) => (semi ? [...vals.slice(0, 3), v, ...vals.slice(3)] : vals);
  const cls = withSemi(['order', 'area', 'rough', 'finish', 'total', 'finished', 'left', 'unreached', 'not-covered'],
                       'semi');
  (f.areas || []).forEach((a, k) => {
    const tr = document.createElement('tr');
    tr.dataset.area = a.area;
    const c = colour.get(a.area);
    tr.innerHTML = cells(withSemi([k + 1, (c ? swatch(c) : '') + a.area, figFmt.minutes(a.roughing_time_s),
      figFmt.minutes(a.finishing_time_s), figFmt.minutes(a.machining_time_s), figFmt.count(a.finished),
      figFmt.count(a.left), figFmt.count(a.unreached), figFmt.count(a.not_covered)],
      figFmt.minutes(a.semi_finishing_time_s)), cls);
    body.appendChild(tr);
  });
  const foot = document.querySelector('#figures tfoot');
  const tr = document.createElement('tr');
  tr.className = 'total';
  tr.innerHTML = cells(withSemi(['', 'plan', '', '', figFmt.minutes(f.machining_time_s), figFmt.count(f.finished),
    figFmt.count(f.left), figFmt.count(f.unreached), figFmt.count(f.not_covered)], ''), cls);
  foot.appendChild(tr);
  const shares = document.createElement('tr');
  shares.className = 'shares';
  shares.innerHTML = cells(withSemi(['', 'share', '', '', figFmt.hmm(f.machining_time_s), figFmt.share(f.finished_share),
    figFmt.share(f.left_share), figFmt.share(f.unreached_share), figFmt.share(f.not_covered_share)], ''), cls);
  foot.appendChild(shares);
  const source = { simulated: 'simulated: the posted programs as the control runs them (feeds, rapids, no acceleration)',
                   estimate: 'estimate: from the tool paths before posting (no tool changes), not simulated',
                   none: 'none: no paths' }[f.time_source] || f.time_source;
  $('figures-time').textContent = f.time_source === 'none' ? 'no' : f.time_source;
  $('figures').hidden = false;
  $('figures-note').innerHTML = '';
  $('figures-note').append(
    `Times in minutes, ${source}; total ${figFmt.hmm(f.machining_time_s)} (h:mm). ` +
    `Counts are of the ${figFmt.count(f.n_points)} input points (the scan's points, not the sampled ones), each in ` +
    'one column: finished within tolerance' + (f.measured ? '' : ' (not simulated: unknown)') + '; left (reached by a ' +
    'finishing move, not finished); unreached (no kept finishing move reaches it); not covered (seen by no chosen ' +
    `set-up). Target: ${figFmt.share(f.target_coverage, 0)} finished.`);
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
// finishing paths in the area's colour, shown from the start; semi-finishing (off at the start) a little
// darker, roughing paths (off at the start) darker;
// both translucent and without depth writes, so the shaded scan stays visible under the passes and
// through the roughing levels; rapids grey, off. The deviation colours hide the paths (they would cover
// the map) and the area colours bring back the switches as they were.
const FINISHING_OPACITY = 0.3, ROUGHING_OPACITY = 0.15;
const pathObjects = [];         // { item, cb, cutLines, rapidLines }
let savedPathSwitches = null;   // the path switches' states while the deviation colours hide them

function pathSwitches() {
  return [...document.querySelectorAll('.toggle-path:not(:disabled), #show-finishing, #show-semi, #show-roughing')];
}

function pathsForColour() {
  const deviation = document.querySelector('input[name=colour]:checked').value === 'deviation';
  if (deviation && !savedPathSwitches) {
    savedPathSwitches = new Map(pathSwitches().map((c) => [c, c.checked]));
    for (const c of savedPathSwitches.keys()) c.checked = false;
  } else if (!deviation && savedPathSwitches) {
    for (const [c, on] of savedPathSwitches) c.checked = on;
    savedPathSwitches = null;
  }
  applyPaths();
}

function applyPaths() {
  const rapids = $('show-rapids').checked;
  for (const p of pathObjects) {
    const on = p.cb ? p.cb.checked : false;
    p.cutLines.visible = on;
    p.rapidLines.visible = on && rapids;
  }
  requestRender();
}

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
    const roughing = item.operation === 'roughing', semi = item.operation === 'semi_finishing';
    const shade = roughing ? 0.5 : (semi ? 0.75 : 1.0);
    const colour = new THREE.Color(c[0] * shade / 255, c[1] * shade / 255, c[2] * shade / 255);
    const gc = new THREE.BufferGeometry(), gr = new THREE.BufferGeometry();
    gc.setAttribute('position', attr); gc.setIndex(new THREE.BufferAttribute(cuts, 1));
    gr.setAttribute('position', attr); gr.setIndex(new THREE.BufferAttribute(rapids, 1));
    const translucent = { transparent: true, opacity: roughing ? ROUGHING_OPACITY : FINISHING_OPACITY, depthWrite: false };
    const cutLines = new THREE.LineSegments(gc, new THREE.LineBasicMaterial({ color: colour, ...translucent }));
    const rapidLines = new THREE.LineSegments(gr, new THREE.LineBasicMaterial({ color: 0x9e9e9e, ...translucent }));
    cutLines.renderOrder = rapidLines.renderOrder = roughing ? 3 : 2;   // after the opaque scan
    for (const o of [cutLines, rapidLines]) { placeQuantised(o, box.min_mm, box.max_mm); o.visible = false; o.frustumCulled = false; scene.add(o); }
    const cb = document.querySelector(`tr[data-setup="${item.area}"] .toggle-path[data-op="${item.operation}"]`);
    if (cb) {
      cb.disabled = false;
      const all = roughing ? $('show-roughing') : (semi ? $('show-semi') : $('show-finishing'));
      if (savedPathSwitches) {       // the deviation colours were chosen while the paths loaded
        savedPathSwitches.set(cb, savedPathSwitches.get(all));
        cb.checked = false;
      } else cb.checked = all.checked;
      cb.onchange = applyPaths;
    }
    pathObjects.push({ item, cb, cutLines, rapidLines });
  }
  // the switches of every area at once
  for (const [id, op] of [['show-finishing', 'finishing'], ['show-semi', 'semi_finishing'], ['show-roughing', 'roughing']]) {
    $(id).onchange = (e) => {
      for (const p of pathObjects) if (p.cb && p.item.operation === op) p.cb.checked = e.target.checked;
      applyPaths();
    };
  }
  $('show-rapids').onchange = applyPaths;
  // a table switch without a path (an area whose operation has no moves) stays off and disabled
  for (const cb of document.querySelectorAll('.toggle-path:disabled')) cb.checked = false;
  applyPaths();
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
  $('counts').textContent = `${shown.toLocaleString('en')} of ${total.toLocaleString('en')} input points shown; ` +
    `${idx.points.n_integrated.toLocaleString('en')} integrated (darker), ` +
    `${idx.points.n_unmachined.toLocaleString('en')} unmachined (red: no kept finishing move reaches them)`;
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
