// voxserve's web client: shows frames rendered on the server and sends the
// view back. No build step; plain ES modules. Every setting's default, range,
// choices and doc come from the server (GET /api/settings, settings.js): the
// client only lays out controls and composes them into view settings.

import { authFetch, logIn } from './auth.js';
import { OrbitCamera, attachGestures } from './camera.js';
import { Schema, control } from './settings.js';
import { PLANES, SliceViews, directionLetters, scaleBarMm } from './slices.js';
import { ViewStream } from './stream.js';
import { StudyBrowser, isoDate, personName } from './studies.js';
import { TfEditor } from './tf-editor.js';

// The full frame's longest side, in device pixels (software GPUs are slow).
// The server renders smaller, lossy frames while the view keeps changing and
// the full lossless frame once it is still.
const MAX_EDGE = 1536;
// The data reductions the Detail menu offers (those within the setting's range).
const REDUCTIONS = [1, 4, 9, 35];
// Where a light turned from directional into a point or spot light starts:
// half-extents of the volume from its centre (outside it), and a spot's
// half-angle. Layout choices of the panel, not settings: the server's
// default light is directional.
const PLACED_DISTANCE = 1.5;
const SPOT_ANGLE = 30;

const canvas = document.getElementById('view');
const context = canvas.getContext('2d');
const presetSelect = document.getElementById('preset');
const reductionSelect = document.getElementById('reduction');
const clipBox = document.getElementById('clip');
const lightPanel = document.getElementById('light-panel');
const errorBox = document.getElementById('error');
const fidelity = document.getElementById('fidelity');
const statusLine = document.getElementById('status');
const saveButton = document.getElementById('save');
const hint = document.getElementById('hint');
const lightInputs = Object.fromEntries(
  ['kind', 'drag', 'azimuth', 'elevation', 'distance', 'spot']
    .map((name) => [name, document.getElementById(`light-${name}`)]),
);
// The toolbar's selects of choice settings, by setting name.
const toolbarSelects = Object.fromEntries(
  [...document.querySelectorAll('#toolbar select[data-setting]')].map((s) => [s.dataset.setting, s]),
);

let schema = null;
let camera = null;
let slices = null;
let dataset = null;
let stream = null;
// The edited transfer function (the `tf` text), or null for the preset's.
let customTf = null;
const tfEditor = new TfEditor(document.getElementById('tf'), document.getElementById('tf-colour'), (text) => {
  customTf = text;
  markEdited();
  requestFrame();
});
// Per lit mode: its light as the panel shows it, and its other settings' controls.
const modes = {
  global: { light: null, controls: [] },
  extinction: { light: null, controls: [] },
};
// The controls of the light's colour and intensity (shared by both modes).
let colourControl = null;
let intensityControl = null;

// Loads the chosen preset's transfer function into the editor.
function loadPreset() {
  customTf = null;
  presetSelect.querySelector('option[value=""]')?.remove();
  const preset = dataset.presets.find((p) => p.name === presetSelect.value);
  if (preset) tfEditor.load(dataset.histogram, dataset.histogram_range, preset.tf);
}

// An edited transfer function is no preset: the menu says which it was edited
// from, so choosing that preset again is a change that restores it.
function markEdited() {
  let edited = presetSelect.querySelector('option[value=""]');
  if (!edited) {
    const from = presetSelect.value;
    edited = new Option(`${from} (edited)`, '');
    edited.title = 'The transfer function as edited; choose a preset to go back to it';
    presetSelect.add(edited, 0);
  }
  presetSelect.value = '';
}

// The status line: plain words for what the image is, the technical
// figures on hover; the spinner turns while more is still to come.
function showStatus(words, detail = '', busy = true) {
  statusLine.textContent = words;
  fidelity.title = detail;
  fidelity.classList.toggle('busy', busy);
}

// What a frame is, in words a radiologist uses.
function plainStatus(info) {
  if (info.emptyShare >= 1) {
    return 'Nothing is visible with this transfer function: widen it, or choose a preset';
  }
  const parts = [info.lossless ? 'Still image' : 'Quick preview while the view changes'];
  if (info.lossless) parts.push(info.reduction <= 1.05 ? 'full detail' : `detail reduced ${info.reduction.toFixed(0)}:1`);
  if (info.memoryLimited) parts.push('memory allows no more detail');
  if (info.directions && info.refined < info.directions) {
    parts.push(`lighting ${Math.round((100 * info.refined) / info.directions)} %`);
  }
  if (info.pendingBlocks) parts.push('loading more detail…');
  return parts.join(' · ');
}

function drawFrame(bitmap, info, blob) {
  if (info.latest && info.lossless) savedFrames[info.pane] = { blob, info };
  saveButton.disabled = !savedFrames[activePane];
  if (info.pane !== '3d') {
    slices.draw(bitmap, info);
    return;
  }
  errorBox.hidden = true;
  context.imageSmoothingEnabled = true;
  context.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
  bitmap.close();
  const quality = info.lossless ? 'lossless' : 'JPEG';
  const light = info.directions ? ` · light ${info.refined}/${info.directions}` : '';
  // Blocks still being read are shown coarser; more detail follows.
  const loading = info.pendingBlocks ? ` · loading ${info.pendingBlocks} blocks` : '';
  const latency = Number.isNaN(info.latencyMs) ? '' : ` · latency ${info.latencyMs.toFixed(0)} ms`;
  // The reduction is among the blocks the transfer function shows (the
  // Detail chosen); the empty share is skipped at every detail.
  const asked = Number(reductionSelect.value);
  const limited = info.memoryLimited ? ` (memory holds no more than this; ${asked}:1 asked)` : '';
  const empty = ` · ${(info.emptyShare * 100).toFixed(0)} % empty`;
  const detail =
    `${info.width}×${info.height} ${quality} · reduction ${info.reduction.toFixed(1)}:1${limited}${empty}` +
    `${light}${loading} · ` +
    `render ${info.renderMs.toFixed(0)} ms · encode ${info.encodeMs.toFixed(0)} ms${latency}`;
  const done = info.latest && info.lossless && info.converged && !info.pendingBlocks;
  showStatus(plainStatus(info), detail, !done);
  canvas.dataset.frames = String(Number(canvas.dataset.frames || 0) + 1);
}

function showError(message) {
  errorBox.textContent = message;
  placeBanner();
  errorBox.hidden = false;
}

// The error banner sits just below the toolbar, whose height changes as it
// wraps and as its panels open.
const toolbar = document.getElementById('toolbar');
function placeBanner() {
  const below = Math.round(toolbar.getBoundingClientRect().bottom + 6);
  errorBox.style.top = `${below}px`;
  document.documentElement.style.setProperty('--panel-top', `${below}px`);
}
new ResizeObserver(placeBanner).observe(toolbar);

function resizeCanvas() {
  const dpr = window.devicePixelRatio || 1;
  canvas.width = Math.max(1, Math.round(canvas.clientWidth * dpr));
  canvas.height = Math.max(1, Math.round(canvas.clientHeight * dpr));
}

// The viewport in CSS pixels and the device pixel ratio, capped so the frame's
// longest side stays within MAX_EDGE.
function viewport() {
  const w = Math.max(1, canvas.clientWidth);
  const h = Math.max(1, canvas.clientHeight);
  const dpr = Math.max(0.25, Math.min(window.devicePixelRatio || 1, MAX_EDGE / Math.max(w, h), 4));
  return { size: { w, h }, dpr: Number(dpr.toFixed(3)) };
}

// Fills a toolbar select with a choice setting's choices, its default chosen.
function fillChoices(select, setting) {
  select.replaceChildren();
  for (const choice of setting.choices) {
    const option = new Option(choice.name, choice.name);
    option.title = choice.doc;
    select.add(option);
  }
  select.value = setting.default;
  select.title = setting.doc;
}

// The Detail menu: data reductions within the setting's range, the default chosen.
function fillReductions(setting) {
  const offered = [...new Set([setting.default, ...REDUCTIONS])]
    .filter((r) => r >= setting.min && r <= setting.max)
    .sort((a, b) => a - b);
  for (const r of offered) reductionSelect.add(new Option(r === 1 ? 'full (1:1)' : `${r}:1`, String(r)));
  reductionSelect.value = String(setting.default);
}

// Clip sliders, [axis][0 = min, 1 = max], values 0..1000, from the clip default.
function buildClipSliders(setting) {
  const [x0, y0, z0, x1, y1, z1] = setting.default.split(',').map(Number);
  const lo = [x0, y0, z0];
  const hi = [x1, y1, z1];
  return ['x', 'y', 'z'].map((axis, a) => {
    const row = document.createElement('div');
    row.className = 'clip-axis';
    row.append(axis);
    const pair = [lo[a], hi[a]].map((value, i) => {
      const slider = document.createElement('input');
      slider.type = 'range';
      slider.min = 0;
      slider.max = 1000;
      slider.value = Math.round(value * 1000);
      slider.title = `${axis} ${i === 0 ? 'from' : 'to'}`;
      slider.setAttribute('aria-label', slider.title);
      row.append(slider);
      return slider;
    });
    const readout = document.createElement('output');
    const show = () => {
      const [from, to] = pair.map((p) => Math.round(Number(p.value) / 10));
      readout.textContent = `${from}–${to} %`;
    };
    for (const slider of pair) slider.addEventListener('input', show);
    show();
    row.append(readout);
    clipBox.append(row);
    return pair;
  });
}
let clipSliders = [];

// The clip setting's text. Keeps each axis's min below its max.
function clipParam() {
  const lo = [];
  const hi = [];
  for (const [min, max] of clipSliders) {
    const a = Math.min(Number(min.value), 999);
    const b = Math.max(Number(max.value), a + 1);
    lo.push(a / 1000);
    hi.push(b / 1000);
  }
  return [...lo, ...hi].join(',');
}

// A light's position text (`kind:…`, as the settings `light` and `lights`
// take it) → the panel's state: the direction from the centre as azimuth
// (0 anterior, 90 the patient's left) and elevation, a distance in
// half-extents for point and spot lights, and a spot's half-angle.
function placement(source) {
  const [kind, at, axis, angle] = source.split(':');
  const xyz = at.split(',').map(Number);
  const v = kind === 'directional' || kind === 'dir' ? xyz : xyz.map((c) => c - 0.5);
  const length = Math.hypot(...v) || 1;
  return {
    kind: kind === 'dir' ? 'directional' : kind,
    azimuth: (Math.atan2(v[0], -v[1]) * 180) / Math.PI,
    elevation: (Math.asin(v[2] / length) * 180) / Math.PI,
    distance: kind === 'directional' || kind === 'dir' ? PLACED_DISTANCE : 2 * length,
    spot: kind === 'spot' ? Number(angle) : SPOT_ANGLE,
    axis,
  };
}

// The panel's light → its position text.
function sourceText(light) {
  const a = (light.azimuth * Math.PI) / 180;
  const e = (light.elevation * Math.PI) / 180;
  const v = [Math.sin(a) * Math.cos(e), -Math.cos(a) * Math.cos(e), Math.sin(e)];
  const xyz = (w) => w.map((c) => c.toFixed(3)).join(',');
  const at = v.map((c) => 0.5 + (c * light.distance) / 2);
  switch (light.kind) {
    case 'point': return `point:${xyz(at)}`;
    case 'spot': return `spot:${xyz(at)}:${xyz(v.map((c) => -c))}:${light.spot}`;
    default: return `directional:${xyz(v)}`;
  }
}

// Each lit mode's light as its settings' defaults say.
function defaultLights() {
  modes.global.light = {
    ...placement(schema.default('light')),
    colour: schema.default('light_colour'),
    intensity: schema.default('light_intensity'),
  };
  modes.extinction.light = firstLight(schema.default('lights'), {
    colour: schema.default('light_colour'),
    intensity: schema.default('light_intensity'),
  }) || { ...modes.global.light };
}

// The panel's state of the first light of a `lights` text
// (`kind:position[:axis:angle]:rrggbb:intensity;…`), its colour and
// intensity from `fallback` where it gives none; null when it has none.
function firstLight(lights, fallback) {
  const first = lights.split(';')[0];
  if (!first) return null;
  const parts = first.split(':');
  const fields = parts[0] === 'spot' ? 4 : 2;
  return {
    ...placement(parts.slice(0, fields).join(':')),
    colour: parts[fields] || fallback.colour,
    intensity: parts[fields + 1] === undefined ? fallback.intensity : Number(parts[fields + 1]),
  };
}

// The current lit mode's entry of `modes`, or null for unlit shading.
function litMode() {
  return modes[toolbarSelects.shading.value] || null;
}

// Shows the panel's controls for the current mode's light.
function showLight() {
  const mode = litMode();
  if (!mode) return;
  const light = mode.light;
  lightInputs.kind.value = light.kind;
  for (const name of ['azimuth', 'elevation', 'distance', 'spot']) {
    lightInputs[name].value = light[name];
    lightInputs[name].nextElementSibling.textContent = Number(light[name].toPrecision(3));
  }
  colourControl.setting.value = light.colour;
  intensityControl.setting.value = light.intensity;
}

// Reads the panel's controls into the current mode's light.
function readLight() {
  const mode = litMode();
  if (!mode) return;
  const light = mode.light;
  light.kind = lightInputs.kind.value;
  for (const name of ['azimuth', 'elevation', 'distance', 'spot']) {
    light[name] = Number(lightInputs[name].value);
    lightInputs[name].nextElementSibling.textContent = Number(light[name].toPrecision(3));
  }
  light.colour = colourControl.setting.value;
  light.intensity = intensityControl.setting.value;
}

// The lit mode's view settings: its light and every control of its group.
function lightParams() {
  const shading = toolbarSelects.shading.value;
  const mode = litMode();
  if (!mode) return {};
  const params = Object.fromEntries(mode.controls.map((c) => [c.dataset.setting, c.setting.value]));
  const light = mode.light;
  if (shading === 'global') {
    // Global light has no spot light: a spot becomes a point light there.
    const source = sourceText(light.kind === 'spot' ? { ...light, kind: 'point' } : light);
    return { ...params, light: source, light_colour: light.colour, light_intensity: light.intensity };
  }
  // The server refuses more shells than the radius: follow the radius down.
  if ('ao_shells' in params && params.ao_shells > params.ao_radius) {
    params.ao_shells = params.ao_radius;
    mode.controls.find((c) => c.dataset.setting === 'ao_shells').setting.value = params.ao_radius;
  }
  return { ...params, lights: `${sourceText(light)}:${light.colour}:${light.intensity}` };
}

// Builds the Illumination panel's controls from the schema: colour and
// intensity of the light, then each lit mode's other settings (advanced
// ones under "More").
function buildLightPanel() {
  const onInput = () => {
    readLight();
    requestFrame();
  };
  colourControl = control(schema.get('light_colour'), onInput);
  intensityControl = control(schema.get('light_intensity'), onInput);
  document.getElementById('light-common').append(colourControl, intensityControl);
  const composed = new Set(['light', 'light_colour', 'light_intensity', 'lights']);
  for (const [name, group] of [['global', 'global_light'], ['extinction', 'extinction']]) {
    for (const setting of schema.inGroup(group)) {
      if (composed.has(setting.name)) continue;
      const c = control(setting, () => requestFrame());
      c.dataset.mode = name;
      modes[name].controls.push(c);
      const where = setting.ui === 'advanced' ? 'light-more' : 'light-settings';
      document.getElementById(where).append(c);
    }
  }
}

// Shows the illumination panel for the lit modes, with the rows of the mode.
function showLightPanel() {
  const mode = toolbarSelects.shading.value;
  lightPanel.hidden = !litMode();
  if (lightPanel.hidden) return;
  if (mode === 'global' && lightInputs.kind.value === 'spot') lightInputs.kind.value = 'point';
  // Rows of another mode, or of another kind of light, are hidden.
  for (const row of lightPanel.querySelectorAll('[data-mode], [data-kind]')) {
    const modeOk = !row.dataset.mode || row.dataset.mode === mode;
    const kindOk = !row.dataset.kind || row.dataset.kind.split(' ').includes(lightInputs.kind.value);
    row.hidden = !(modeOk && kindOk);
  }
}

// Dragging on the image moves the light instead of the camera while the
// panel's box is ticked or Shift is held; the wheel moves a point or spot light
// nearer or farther (into the volume below distance 1).
function attachLightDrag() {
  let last = null;
  const active = (e) => !lightPanel.hidden && (lightInputs.drag.checked || e.shiftKey);
  canvas.addEventListener('pointerdown', (e) => {
    if (!active(e)) return;
    e.stopImmediatePropagation();
    canvas.setPointerCapture(e.pointerId);
    last = { id: e.pointerId, x: e.clientX, y: e.clientY };
  }, { capture: true });
  canvas.addEventListener('pointermove', (e) => {
    if (!last || e.pointerId !== last.id) return;
    e.stopImmediatePropagation();
    const light = litMode().light;
    light.azimuth = ((light.azimuth - (e.clientX - last.x) * 0.5 + 540) % 360) - 180;
    light.elevation = Math.max(-90, Math.min(90, light.elevation - (e.clientY - last.y) * 0.5));
    last = { id: e.pointerId, x: e.clientX, y: e.clientY };
    showLight();
    requestFrame();
  }, { capture: true });
  const end = (e) => {
    if (!last || e.pointerId !== last.id) return;
    e.stopImmediatePropagation();
    last = null;
    requestFrame();
  };
  canvas.addEventListener('pointerup', end, { capture: true });
  canvas.addEventListener('pointercancel', end, { capture: true });
  canvas.addEventListener('wheel', (e) => {
    if (!active(e) || lightInputs.kind.value === 'directional') return;
    e.preventDefault();
    e.stopImmediatePropagation();
    const light = litMode().light;
    light.distance = Math.min(Number(lightInputs.distance.max), light.distance * Math.exp(e.deltaY * 0.001));
    showLight();
    requestFrame();
  }, { capture: true, passive: false });
}

// The whole view as the controls and the camera hold it (view settings by name).
function currentView() {
  const choices = Object.fromEntries(Object.entries(toolbarSelects).map(([name, s]) => [name, s.value]));
  return {
    dataset: dataset.id,
    ...camera.params(),
    ...viewport().size,
    ...(customTf ? { tf: customTf } : { preset: presetSelect.value }),
    ...choices,
    reduction: Number(reductionSelect.value),
    clip: clipParam(),
    ...lightParams(),
  };
}

// Sends the view; the server renders what it needs (it sees the messages come
// and renders small lossy frames while they do).
function requestFrame() {
  if (!dataset || !stream) return;
  const view = currentView();
  const { dpr } = viewport();
  const sent = stream.update(view, dpr);
  if (sent) {
    fidelity.classList.add('busy');
    delete savedFrames['3d'];
  }
  for (const [plane, sliceView] of Object.entries(slices.views())) {
    if (stream.update(sliceView, dpr, plane)) {
      slices.markBusy([plane]);
      delete savedFrames[plane];
    }
  }
  saveButton.disabled = !savedFrames[activePane];
  slices.redraw();
  linkView(view);
  showOrientation();
}

// The layouts, by the key that chooses them: the views each shows.
const LAYOUTS = {
  1: ['3d'],
  2: ['axial', '3d', 'coronal', 'sagittal'],
  3: ['3d', 'axial', 'coronal', 'sagittal'],
  4: ['axial'],
};
const layoutSelect = document.getElementById('layout');
const orientationBox = document.getElementById('orientation');

// Each shown view's rectangle (CSS pixels) in layout `key` of a window
// `width` × `height` whose views start `top` pixels down (below the
// toolbar, except the 3D view alone, which fills the window).
function layoutRects(key, width, height, top) {
  const panes = LAYOUTS[key];
  const gap = 2;
  if (panes.length === 1) {
    const y = panes[0] === '3d' ? 0 : top;
    return { [panes[0]]: { left: 0, top: y, width, height: height - y } };
  }
  const h = height - top;
  const rects = {};
  if (key === '2') {
    const w2 = (width - gap) / 2;
    const h2 = (h - gap) / 2;
    panes.forEach((pane, i) => {
      rects[pane] = { left: (i % 2) * (w2 + gap), top: top + Math.floor(i / 2) * (h2 + gap), width: w2, height: h2 };
    });
    return rects;
  }
  // 1+3: the 3D view large, the slices beside it (below it on a tall screen).
  if (width >= h) {
    const side = Math.round(width / 3);
    rects['3d'] = { left: 0, top, width: width - side - gap, height: h };
    const each = (h - 2 * gap) / 3;
    PLANES.forEach((pane, i) => {
      rects[pane] = { left: width - side, top: top + i * (each + gap), width: side, height: each };
    });
  } else {
    const strip = Math.round(h / 3);
    rects['3d'] = { left: 0, top, width, height: h - strip - gap };
    const each = (width - 2 * gap) / 3;
    PLANES.forEach((pane, i) => {
      rects[pane] = { left: i * (each + gap), top: top + h - strip, width: each, height: strip };
    });
  }
  return rects;
}

// Lays the views out as the layout menu says, and tells the server which to render.
function applyLayout() {
  const key = layoutSelect.value;
  // The slices' controls only while slices show.
  for (const el of toolbar.querySelectorAll('[data-slices]')) el.hidden = key === '1';
  const top = Math.round(toolbar.getBoundingClientRect().bottom + 4);
  const rects = layoutRects(key, window.innerWidth, window.innerHeight, top);
  const three = rects['3d'];
  canvas.hidden = !three;
  orientationBox.hidden = !three;
  if (three) {
    for (const el of [canvas, orientationBox]) {
      Object.assign(el.style, {
        left: `${three.left}px`, top: `${three.top}px`, width: `${three.width}px`, height: `${three.height}px`,
      });
    }
    // The top letter clears the toolbar when the view starts under it.
    const below = Math.max(6, Math.round(toolbar.getBoundingClientRect().bottom + 6 - three.top));
    document.getElementById('orient-top').style.top = `${below}px`;
  }
  // The patient and study over the 3D view, else over the first view.
  const host = three || rects[LAYOUTS[key][0]];
  const context = document.getElementById('context');
  Object.assign(context.style, {
    left: `${host.left}px`, top: `${host.top}px`, width: `${host.width}px`, height: `${host.height}px`,
  });
  const clear = Math.max(22, Math.round(toolbar.getBoundingClientRect().bottom + 22 - host.top));
  context.style.setProperty('--context-top', `${clear}px`);
  document.body.dataset.layout = key;
  // Save image saves a view that shows: the 3D view, else the first.
  if (!LAYOUTS[key].includes(activePane)) activePane = LAYOUTS[key].includes('3d') ? '3d' : LAYOUTS[key][0];
  saveButton.disabled = !savedFrames[activePane];
  resizeCanvas();
  slices.place(rects, viewport().dpr);
  if (stream) stream.setLayout(LAYOUTS[key]);
}

function chooseLayout(key) {
  if (!(key in LAYOUTS)) return;
  layoutSelect.value = key;
  applyLayout();
  requestFrame();
}

// The slice views' window menu: the dataset's default, then its named
// windows by number (Shift+1 … on the keyboard), and "custom" once dragged.
const windowSelect = document.getElementById('window-preset');
function fillWindows() {
  windowSelect.replaceChildren();
  const d = dataset.default_window;
  windowSelect.add(new Option(`default (${d.name} ${round1(d.centre)}/${round1(d.width)})`, ''));
  dataset.windows.forEach((w, i) => {
    windowSelect.add(new Option(`${i + 1} ${w.name} (${w.centre}/${w.width})`, String(i + 1)));
  });
  const custom = new Option('custom (dragged)', 'custom');
  custom.disabled = true;
  windowSelect.add(custom);
  windowSelect.value = '';
}
function round1(v) {
  return Number(v.toPrecision(4));
}
function chooseWindow(number) {
  const w = dataset.windows[number - 1];
  if (!w) return;
  windowSelect.value = String(number);
  slices.setWindow({ centre: w.centre, width: w.width });
}

// The measurements' list, with each one's slice.
function listMeasurements() {
  const list = document.getElementById('measurements');
  list.replaceChildren();
  for (const m of slices.measurements) {
    const item = document.createElement('li');
    item.textContent = `${m.kind} ${slices.describe(m)} (${m.plane})`;
    item.dataset.value = String(m.value);
    list.append(item);
  }
  document.getElementById('measure-panel').querySelector('summary').textContent =
    `Measure${slices.measurements.length ? ` (${slices.measurements.length})` : ''}`;
}

// A click on the 3D view (a press and release without a drag) moves the
// crosshair to the first point the view shows there, when slices are shown.
function attachPick() {
  let down = null;
  canvas.addEventListener('pointerdown', (e) => {
    down = e.button === 0 && !e.ctrlKey && !e.shiftKey ? { x: e.clientX, y: e.clientY, t: performance.now() } : null;
  });
  canvas.addEventListener('pointerup', async (e) => {
    if (!down || Math.hypot(e.clientX - down.x, e.clientY - down.y) > 4 || performance.now() - down.t > 600) return;
    down = null;
    if (LAYOUTS[layoutSelect.value].length === 1) return;
    const r = canvas.getBoundingClientRect();
    const answer = await stream.ask('pick', { xy: [e.clientX - r.left, e.clientY - r.top] });
    if (answer && answer.at) slices.moveCrosshair(answer.at);
    else if (answer) showError('nothing visible under that point to put the crosshair on');
  });
}

// Keys anywhere but in a control: 1–4 choose the layout, Shift+1… the
// slice window by number, R resets every view.
function attachKeys() {
  document.addEventListener('keydown', (e) => {
    if (e.altKey || e.ctrlKey || e.metaKey) return;
    if (e.target.closest && e.target.closest('input, select, textarea, summary, button')) return;
    const digit = /^Digit([1-9])$/.exec(e.code);
    if (digit && e.shiftKey) chooseWindow(Number(digit[1]));
    else if (digit && digit[1] in LAYOUTS) chooseLayout(digit[1]);
    else if (e.key === 'r' || e.key === 'R') {
      camera.reset();
      slices.reset();
      windowSelect.value = '';
      requestFrame();
    } else return;
    e.preventDefault();
  });
}

// The view in the address, so a link reproduces it: every setting sent but
// the image size (the window's) and a pending fit, as the hash's query with
// the settings' own names and text forms.
const UNLINKED = new Set(['w', 'h', 'fit']);
function linkView(view) {
  const params = new URLSearchParams();
  // Until a fit is answered, the camera is the server's to choose.
  const unsettled = view.fit ? new Set(Object.keys(camera.params())) : new Set();
  for (const [name, value] of Object.entries(view)) {
    if (!UNLINKED.has(name) && !unsettled.has(name)) params.set(name, String(value));
  }
  if (layoutSelect.value !== '1') params.set('layout', layoutSelect.value);
  slices.linkParams(params);
  const address = `${location.pathname}${location.search}#${params}`;
  if (address !== `${location.pathname}${location.search}${location.hash}`) {
    history.replaceState(null, '', address);
  }
}

// A linked value typed as its setting takes it.
function typed(name, text) {
  const setting = schema.settings.get(name);
  if (!setting) return text;
  if (['number', 'whole', 'one_of'].includes(setting.kind)) return Number(text);
  if (setting.kind === 'bool') return text === 'true';
  return text;
}

// Sets the controls and the camera from a link's hash (before the first
// view goes); the server checks every value as from any other client.
function applyLink() {
  const params = new URLSearchParams(location.hash.slice(1));
  const get = (name) => params.get(name);
  if (![...params.keys()].some((name) => schema.settings.has(name) || name === 'layout')) return;
  if (get('dataset') !== null) chooseDataset(get('dataset'));
  if (get('layout') !== null && get('layout') in LAYOUTS) layoutSelect.value = get('layout');
  slices.applyLink(params);
  if (get('swindow') !== null) windowSelect.value = '';
  if (get('preset') !== null && dataset.presets.some((p) => p.name === get('preset'))) {
    presetSelect.value = get('preset');
    loadPreset();
  }
  if (get('tf') !== null) {
    tfEditor.load(dataset.histogram, dataset.histogram_range, get('tf'));
    customTf = get('tf');
    markEdited();
  }
  for (const [name, select] of Object.entries(toolbarSelects)) {
    if (get(name) !== null) select.value = get(name);
  }
  if (get('reduction') !== null) {
    const r = get('reduction');
    if (![...reductionSelect.options].some((o) => o.value === r)) reductionSelect.add(new Option(`${r}:1`, r));
    reductionSelect.value = r;
  }
  if (get('clip') !== null) {
    const values = get('clip').split(',').map(Number);
    clipSliders.forEach((pair, axis) => {
      pair[0].value = Math.round(values[axis] * 1000);
      pair[1].value = Math.round(values[axis + 3] * 1000);
      pair[0].dispatchEvent(new Event('input'));
    });
  }
  const cameraNames = ['az', 'el', 'dist', 'tx', 'ty', 'tz'];
  if (cameraNames.some((name) => get(name) !== null)) {
    const set = Object.fromEntries(cameraNames.filter((n) => get(n) !== null).map((n) => [n, Number(get(n))]));
    if ('az' in set) camera.az = set.az;
    if ('el' in set) camera.el = set.el;
    camera.adopt(set);
  }
  if (get('light') !== null) {
    modes.global.light = {
      ...placement(get('light')),
      colour: get('light_colour') ?? modes.global.light.colour,
      intensity: get('light_intensity') !== null ? Number(get('light_intensity')) : modes.global.light.intensity,
    };
  }
  if (get('lights')) modes.extinction.light = firstLight(get('lights'), modes.extinction.light);
  for (const mode of Object.values(modes)) {
    for (const c of mode.controls) {
      const value = get(c.dataset.setting);
      if (value !== null) c.setting.value = typed(c.dataset.setting, value);
    }
  }
}

// Orientation labels at the view's edges and a scale bar in mm (at the
// camera's target, the depth the view turns about).
function showOrientation() {
  // The cube turns with the camera: about the patient's long axis by the
  // azimuth, then tilted by the elevation (CSS: x right, y down, z out).
  document.getElementById('cube-body').style.transform = `rotateX(${-camera.el}deg) rotateY(${-camera.az}deg)`;
  const marker = document.getElementById('crosshair-3d');
  const at = LAYOUTS[layoutSelect.value].length > 1 && slices
    ? camera.project(slices.crosshair, canvas.clientWidth, canvas.clientHeight, toolbarSelects.proj.value === 'orthographic')
    : null;
  marker.hidden = !at;
  if (at) {
    marker.style.left = `${at[0]}px`;
    marker.style.top = `${at[1]}px`;
  }
  const { right, up } = camera.axes();
  const neg = (v) => v.map((c) => -c);
  const edges = { right, left: neg(right), top: up, bottom: neg(up) };
  for (const [edge, v] of Object.entries(edges)) {
    document.getElementById(`orient-${edge}`).textContent = directionLetters(v);
  }
  const mmPerPixel = camera.mmPerPixel(canvas.clientHeight);
  // The longest 1, 2 or 5 × 10^k mm bar within 120 CSS pixels.
  const best = scaleBarMm(mmPerPixel, 120);
  const bar = document.getElementById('scale');
  if (!best) {
    bar.hidden = true;
    return;
  }
  bar.hidden = false;
  bar.querySelector('div').style.width = `${(best / mmPerPixel).toFixed(1)}px`;
  bar.querySelector('span').textContent = `${Number(best.toPrecision(2))} mm`;
}

// Per view, its last lossless frame of the view sent last (as the server
// encoded it, lossless WebP or PNG), for the Save image button, which saves
// the view used last (clicked, touched or focused; the 3D view at first).
const savedFrames = {};
let activePane = '3d';
function attachActivePane() {
  const choose = (e) => {
    const pane = e.target.closest && e.target.closest('.slice-pane');
    if (pane) activePane = pane.dataset.pane;
    else if (e.target === canvas) activePane = '3d';
    else return;
    saveButton.disabled = !savedFrames[activePane];
  };
  document.addEventListener('pointerdown', choose, true);
  document.addEventListener('focusin', choose);
}

// Downloads that frame as a PNG, the same pixels.
async function saveImage() {
  const saved = savedFrames[activePane];
  if (!saved) {
    showError('no full frame yet: wait until the image is still and lossless');
    return;
  }
  const { blob, info } = saved;
  let png = blob;
  if (blob.type !== 'image/png') {
    const bitmap = await createImageBitmap(blob);
    const canvas2 = new OffscreenCanvas(info.width, info.height);
    canvas2.getContext('2d').drawImage(bitmap, 0, 0);
    bitmap.close();
    png = await canvas2.convertToBlob({ type: 'image/png' });
  }
  const link = document.getElementById('download');
  if (link.href) URL.revokeObjectURL(link.href);
  link.href = URL.createObjectURL(png);
  // What was saved stays on the link for inspection (the page's CSP lets it
  // fetch nothing but its server, blob: addresses included).
  link.saved = png;
  const stamp = new Date().toISOString().replace(/[:.]/g, '-');
  const view = activePane === '3d' ? '' : `-${activePane}`;
  link.download = `voxserve-${dataset.id}${view}-${stamp}.png`;
  link.click();
}

// The dataset picker: the server's datasets, the first chosen.
const datasetSelect = document.getElementById('dataset');
let datasets = [];

// The patient and the study of the current dataset in the image's corners.
function showContext() {
  const s = dataset.study || {};
  const patient = [
    s.patient_name ? personName(s.patient_name) : '',
    s.patient_id ? `ID ${s.patient_id}` : '',
    s.patient_birth_date ? `born ${isoDate(s.patient_birth_date)}` : '',
  ];
  const thickness = s.slice_thickness_mm ? `${Number(s.slice_thickness_mm.toPrecision(3))} mm slices` : '';
  const study = [
    s.study_date ? isoDate(s.study_date) : '',
    s.study_description || '',
    s.series_description || dataset.name,
    [dataset.modality, thickness].filter(Boolean).join(' · '),
  ];
  document.getElementById('context-patient').textContent = patient.filter(Boolean).join('\n');
  document.getElementById('context-study').textContent = study.filter(Boolean).join('\n');
}

// What this browser remembers for the page (null when storage is off: then
// nothing is remembered, and every visit starts afresh).
function recalled(key) {
  try {
    return localStorage.getItem(key);
  } catch {
    return null;
  }
}
function remember(key, value) {
  try {
    localStorage.setItem(key, value);
  } catch {
    // Storage is off: see `recalled`.
  }
}

// The Info button shows or hides the corners (remembered in this browser).
const CONTEXT_SHOWN = 'voxserve.context';
function attachContext() {
  const box = document.getElementById('context');
  const button = document.getElementById('context-toggle');
  const show = (on) => {
    box.hidden = !on;
    button.setAttribute('aria-pressed', String(on));
  };
  show(recalled(CONTEXT_SHOWN) !== '0');
  button.addEventListener('click', () => {
    const on = box.hidden;
    show(on);
    remember(CONTEXT_SHOWN, on ? '1' : '0');
  });
}

// Makes dataset `id` (or the first) the current one, with its presets.
function chooseDataset(id) {
  dataset = datasets.find((d) => d.id === id) || datasets[0];
  camera.setRadius(dataset.radius_mm);
  showContext();
  datasetSelect.value = dataset.id;
  presetSelect.replaceChildren();
  for (const preset of dataset.presets) {
    const option = new Option(preset.name, preset.name);
    option.title = preset.description;
    presetSelect.add(option);
  }
  presetSelect.value = dataset.default_preset;
  loadPreset();
  slices.setDataset(dataset);
  fillWindows();
}

function fillDatasetPicker(list) {
  datasets = list;
  datasetSelect.replaceChildren();
  for (const d of list) {
    const [nx, ny, nz] = d.dims;
    // A series opened or received is named by its UID: its description
    // (and modality) say more.
    const s = d.study || {};
    const named = /^[\d.]+$/.test(d.name) && s.series_description
      ? [d.modality, s.series_description].filter(Boolean).join(' ')
      : d.name;
    datasetSelect.add(new Option(`${named} ${nx}×${ny}×${nz}`, d.id));
  }
}

function buildDatasetPicker(list) {
  fillDatasetPicker(list);
  chooseDataset(list[0].id);
  datasetSelect.addEventListener('change', () => {
    chooseDataset(datasetSelect.value);
    camera.reset();
    requestFrame();
  });
}

// Every session's hello lists the datasets the server offers now: after a
// restart the list may have changed. The current dataset stays if it is
// still offered; if it is gone, the first is shown, and the user told.
function adoptHello(message) {
  const notice = document.getElementById('notice');
  notice.textContent = message.notice || '';
  notice.hidden = !message.notice;
  if (!canvas.dataset.frames) showStatus(`Drawing the first view of ${dataset ? dataset.name : 'the dataset'}…`);
  const list = message.datasets || [];
  const same = list.length === datasets.length && list.every((d, i) => d.id === datasets[i].id);
  if (same) return;
  const current = dataset;
  if (list.length === 0) {
    showError('the server offers no datasets now');
    return;
  }
  fillDatasetPicker(list);
  if (current && list.some((d) => d.id === current.id)) {
    dataset = list.find((d) => d.id === current.id);
    datasetSelect.value = dataset.id;
    camera.setRadius(dataset.radius_mm);
    showContext();
    return;
  }
  chooseDataset(list[0].id);
  camera.reset();
  requestFrame();
  showError(`${current ? current.name : 'the dataset'} is no longer offered by the server: showing ${dataset.name}`);
}

// The toolbar's panels open one at a time; on phones the menu button folds
// the toolbar to one row.
function attachPanels() {
  const panels = [...toolbar.querySelectorAll(':scope > details')];
  for (const panel of panels) {
    panel.addEventListener('toggle', () => {
      if (!panel.open) return;
      hint.hidden = true;
      for (const other of panels) if (other !== panel) other.open = false;
      placeBanner();
    });
  }
  const menu = document.getElementById('menu');
  menu.addEventListener('click', () => {
    const open = toolbar.classList.toggle('open');
    menu.setAttribute('aria-expanded', String(open));
    menu.title = open ? 'Hide the controls' : 'Show the controls';
  });
}

function attachControls() {
  presetSelect.addEventListener('change', () => {
    loadPreset();
    requestFrame();
  });
  for (const select of [...Object.values(toolbarSelects), reductionSelect]) {
    select.addEventListener('change', () => requestFrame());
  }
  toolbarSelects.shading.addEventListener('change', () => {
    showLight();
    showLightPanel();
  });
  for (const slider of clipSliders.flat()) {
    slider.addEventListener('input', () => requestFrame());
  }
  for (const name of ['azimuth', 'elevation', 'distance', 'spot']) {
    lightInputs[name].addEventListener('input', () => {
      readLight();
      requestFrame();
    });
  }
  lightInputs.kind.addEventListener('change', () => {
    readLight();
    showLightPanel();
    requestFrame();
  });
  saveButton.addEventListener('click', saveImage);
  // A link pasted into this tab's address bar changes only the hash.
  window.addEventListener('hashchange', () => {
    applyLink();
    applyLayout();
    showLight();
    showLightPanel();
    requestFrame();
  });
  document.getElementById('reset').addEventListener('click', () => {
    camera.reset();
    slices.reset();
    windowSelect.value = '';
    requestFrame();
  });
  window.addEventListener('resize', () => {
    applyLayout();
    requestFrame();
  });
  layoutSelect.addEventListener('change', () => chooseLayout(layoutSelect.value));
  windowSelect.addEventListener('change', () => {
    if (windowSelect.value === '') slices.setWindow(null);
    else chooseWindow(Number(windowSelect.value));
  });
  const slab = document.getElementById('slab');
  const slabMode = document.getElementById('slab-mode');
  const slabSetting = schema.slice.get('slab');
  slab.min = slabSetting.min;
  slab.max = Math.min(slabSetting.max, 100);
  slab.step = 'any';
  slab.value = slabSetting.default;
  slab.title = slabSetting.doc;
  fillChoices(slabMode, schema.slice.get('slab_mode'));
  const showSlab = () => {
    slab.nextElementSibling.textContent = `${Number(Number(slab.value).toFixed(1))} mm`;
  };
  showSlab();
  slab.addEventListener('input', () => {
    slices.slab = Number(Number(slab.value).toFixed(1));
    showSlab();
    requestFrame();
  });
  slabMode.addEventListener('change', () => {
    slices.slabMode = slabMode.value;
    requestFrame();
  });
  const measure = document.getElementById('measure');
  measure.addEventListener('change', () => {
    slices.measure = measure.value;
    slices.pendingPoints = null;
  });
  document.getElementById('measure-clear').addEventListener('click', () => slices.clearMeasurements());
}

// The interaction hint shows until the user first moves the view or closes
// it (remembered in this browser); the toolbar's "?" shows it again.
const HINTED = 'voxserve.hinted';
function attachHint() {
  hint.hidden = recalled(HINTED) === '1';
  const dismiss = () => {
    hint.hidden = true;
    remember(HINTED, '1');
  };
  document.getElementById('hint-close').addEventListener('click', dismiss);
  canvas.addEventListener('pointerdown', dismiss);
  canvas.addEventListener('wheel', dismiss, { passive: true });
  document.getElementById('help').addEventListener('click', () => {
    hint.hidden = !hint.hidden;
  });
}

// The page-wide notice while a series opens from the PACS: `fraction`
// (0 to 1) and words, or nothing (null) to take it away.
const opening = document.getElementById('opening');
function showOpening(fraction, words = '') {
  if (fraction === null) {
    if (!opening.classList.contains('failed')) opening.hidden = true;
    return;
  }
  opening.hidden = false;
  document.getElementById('opening-progress').value = fraction;
  document.getElementById('opening-words').textContent = words;
}

// Why a launch cannot be shown, over the whole page (not a blank viewer).
function showLaunchFailed(message) {
  opening.classList.add('failed');
  opening.hidden = false;
  document.getElementById('opening-title').textContent = 'Cannot show the images';
  document.getElementById('opening-words').textContent = message;
}

// Dataset `id`, just offered by the server, shown from its default view
// (`again`: the whole series in place of its preview, from the same view).
async function showOpened(id, { again = false } = {}) {
  const response = await authFetch('/api/datasets');
  if (!response.ok) throw new Error(`GET /api/datasets answered ${response.status}`);
  fillDatasetPicker(await response.json());
  chooseDataset(id);
  if (again) stream.resendAll();
  else camera.reset();
  requestFrame();
}

// While a preview of a series shows (a sample of its images), how the rest
// arrives; null when the whole series shows.
const previewNote = document.getElementById('preview-note');
function showPreviewProgress(fraction, words = '') {
  previewNote.hidden = fraction === null;
  previewNote.textContent = fraction === null ? '' : `Preview (a sample of the images) · ${words}`;
}

// The study browser, shown when the server has a PACS; a launch (IHE
// Invoke Image Display sends the browser to `#iid=QUERY`) opens its study.
async function attachStudies(launch) {
  const browser = new StudyBrowser(document.getElementById('studies-panel'), {
    onOpened: showOpened,
    onProgress: showOpening,
    onPreviewProgress: showPreviewProgress,
  });
  const available = await browser.start();
  if (launch === null) return;
  if (!available) {
    showLaunchFailed('This server cannot search a PACS for you (none is configured, or your role may not).');
    return;
  }
  showOpening(0, 'Finding the study on the PACS…');
  try {
    const shown = await browser.invoke(launch);
    if (shown === null) showOpening(null);
  } catch (e) {
    showLaunchFailed(e.message);
  }
}

async function start() {
  // A launch's request, read before the view's link replaces the hash.
  const launch = new URLSearchParams(location.hash.slice(1)).get('iid');
  if (launch !== null) showOpening(0, 'Logging in…');
  resizeCanvas();
  attachHint();
  showStatus('Loading the settings and the list of datasets…');
  let offered;
  try {
    await logIn();
  } catch (e) {
    showError(`cannot log in: ${e.message}`);
    return;
  }
  try {
    const [loaded, response] = await Promise.all([Schema.load(), authFetch('/api/datasets')]);
    schema = loaded;
    offered = await response.json();
  } catch (e) {
    showError(`cannot load the settings or the dataset list: ${e.message}`);
    return;
  }
  camera = new OrbitCamera(schema);
  slices = new SliceViews(schema.slice, {
    ask: (type, fields) => (stream ? stream.ask(type, fields) : Promise.resolve(null)),
  }, {
    onChange: () => {
      if (windowSelect.value !== '' && slices.window) {
        const w = dataset.windows[Number(windowSelect.value) - 1];
        if (!w || w.centre !== slices.window.centre || w.width !== slices.window.width) windowSelect.value = 'custom';
      }
      requestFrame();
    },
    onMeasure: () => listMeasurements(),
    onError: (message) => showError(message),
  });
  for (const [name, select] of Object.entries(toolbarSelects)) fillChoices(select, schema.get(name));
  fillReductions(schema.get('reduction'));
  clipSliders = buildClipSliders(schema.get('clip'));
  buildLightPanel();
  defaultLights();
  buildDatasetPicker(offered);
  applyLink();
  stream = new ViewStream(drawFrame, showError, adoptHello, (set) => {
    camera.adopt(set);
    linkView(currentView());
    showOrientation();
    return camera.params();
  }, (attempts) => {
    canvas.dataset.attempts = String(attempts);
  });
  showStatus(`Connecting to the server to show ${dataset.name}…`);
  attachLightDrag();
  attachPanels();
  attachContext();
  attachGestures(canvas, camera, () => requestFrame());
  attachPick();
  attachKeys();
  attachActivePane();
  attachControls();
  applyLayout();
  showLight();
  showLightPanel();
  requestFrame();
  attachStudies(launch);
}

start();
