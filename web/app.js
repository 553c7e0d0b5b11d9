// voxserve's web client: shows frames rendered on the server and sends the
// camera and transfer-function choices back. No build step; plain ES modules.

import { OrbitCamera, attachGestures } from './camera.js';
import { ViewStream } from './stream.js';
import { TfEditor } from './tf-editor.js';

// The full frame's longest side, in device pixels (software GPUs are slow).
// The server renders smaller, lossy frames while the view keeps changing and
// the full lossless frame once it is still.
const MAX_EDGE = 1536;

const canvas = document.getElementById('view');
const context = canvas.getContext('2d');
const presetSelect = document.getElementById('preset');
const shadingSelect = document.getElementById('shading');
const compositingSelect = document.getElementById('compositing');
const projectionSelect = document.getElementById('projection');
const reductionSelect = document.getElementById('reduction');
const clipBox = document.getElementById('clip');
const lightPanel = document.getElementById('light-panel');
const light = Object.fromEntries(
  ['kind', 'drag', 'azimuth', 'elevation', 'distance', 'colour', 'intensity', 'bias', 'scatter',
    'ambient', 'ao-radius', 'ao-strength', 'bleeding', 'cone', 'spot']
    .map((name) => [name, document.getElementById(`light-${name}`)]),
);
const errorBox = document.getElementById('error');
const fidelity = document.getElementById('fidelity');

const camera = new OrbitCamera();
let dataset = null;
let stream = null;
// The edited transfer function (the `tf` text), or null for the preset's.
let customTf = null;
const tfEditor = new TfEditor(document.getElementById('tf'), document.getElementById('tf-colour'), (text) => {
  customTf = text;
  requestFrame(true);
});

// Loads the chosen preset's transfer function into the editor.
function loadPreset() {
  customTf = null;
  const preset = dataset.presets.find((p) => p.name === presetSelect.value);
  if (preset) tfEditor.load(dataset.histogram, dataset.histogram_range, preset.tf);
}

function drawFrame(bitmap, info) {
  errorBox.hidden = true;
  context.imageSmoothingEnabled = true;
  context.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
  bitmap.close();
  const quality = info.lossless ? 'lossless' : 'JPEG';
  const light = info.directions ? ` · light ${info.refined}/${info.directions}` : '';
  const latency = Number.isNaN(info.latencyMs) ? '' : ` · latency ${info.latencyMs.toFixed(0)} ms`;
  fidelity.textContent =
    `${info.width}×${info.height} ${quality} · reduction ${info.reduction.toFixed(1)}:1${light} · ` +
    `render ${info.renderMs.toFixed(0)} ms · encode ${info.encodeMs.toFixed(0)} ms${latency}`;
  canvas.dataset.frames = String(Number(canvas.dataset.frames || 0) + 1);
}

function showError(message) {
  errorBox.textContent = message;
  errorBox.hidden = false;
}

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

// Clip sliders: [axis][0 = min, 1 = max], values 0..1000.
const clipSliders = ['x', 'y', 'z'].map((axis) => {
  const row = document.createElement('div');
  row.className = 'clip-axis';
  row.append(axis);
  const pair = [0, 1000].map((value, i) => {
    const slider = document.createElement('input');
    slider.type = 'range';
    slider.min = 0;
    slider.max = 1000;
    slider.value = value;
    slider.title = `${axis} ${i === 0 ? 'from' : 'to'}`;
    row.append(slider);
    return slider;
  });
  clipBox.append(row);
  return pair;
});

// The clip box parameter. Keeps each axis's min below its max.
function clipParam() {
  const lo = [];
  const hi = [];
  for (const [min, max] of clipSliders) {
    const a = Math.min(Number(min.value), 999);
    const b = Math.max(Number(max.value), a + 1);
    lo.push(a / 1000);
    hi.push(b / 1000);
  }
  return { clip: [...lo, ...hi].join(',') };
}

// The light of the illumination panel as `kind:…` text (view settings `light`
// and `lights`), with the direction from the centre in patient LPS: azimuth 0
// is anterior (−y), 90 the patient's left (+x).
function lightSource() {
  const a = (Number(light.azimuth.value) * Math.PI) / 180;
  const e = (Number(light.elevation.value) * Math.PI) / 180;
  const v = [Math.sin(a) * Math.cos(e), -Math.cos(a) * Math.cos(e), Math.sin(e)];
  const xyz = (w) => w.map((c) => c.toFixed(3)).join(',');
  const r = Number(light.distance.value) / 200;
  const at = v.map((c) => 0.5 + c * r);
  switch (light.kind.value) {
    case 'point': return `point:${xyz(at)}`;
    case 'spot': return `spot:${xyz(at)}:${xyz(v.map((c) => -c))}:${light.spot.value}`;
    default: return `directional:${xyz(v)}`;
  }
}

// The illumination panel's view settings for the lit shading modes.
function lightParams() {
  const colour = light.colour.value.slice(1);
  const intensity = Number(light.intensity.value) / 100;
  if (shadingSelect.value === 'global') {
    // Global light has no spot light: a spot becomes a point light there.
    const source = lightSource().replace(/^spot:([^:]*):.*$/, 'point:$1');
    return {
      light: source,
      light_colour: colour,
      light_intensity: intensity,
      bias: Number(light.bias.value) / 100,
      scatter_radius: light.scatter.value,
    };
  }
  if (shadingSelect.value === 'extinction') {
    return {
      lights: `${lightSource()}:${colour}:${intensity}`,
      ambient: Number(light.ambient.value) / 100,
      ao_radius: light['ao-radius'].value,
      ao_shells: Math.min(3, Number(light['ao-radius'].value)),
      ao_strength: Number(light['ao-strength'].value) / 100,
      colour_bleeding: light.bleeding.checked,
      cone_angle: light.cone.value,
    };
  }
  return {};
}

// Shows the illumination panel for the lit modes, with the rows of the mode.
function showLightPanel() {
  const mode = shadingSelect.value;
  lightPanel.hidden = mode !== 'global' && mode !== 'extinction';
  if (mode === 'global' && light.kind.value === 'spot') light.kind.value = 'point';
  // Rows of another mode, or of another kind of light, are hidden.
  for (const row of lightPanel.querySelectorAll('[data-mode], [data-kind]')) {
    const modeOk = !row.dataset.mode || row.dataset.mode === mode;
    const kindOk = !row.dataset.kind || row.dataset.kind.split(' ').includes(light.kind.value);
    row.hidden = !(modeOk && kindOk);
  }
}

// Dragging on the image moves the light instead of the camera while the
// panel's box is ticked or Shift is held; the wheel moves a point or spot light
// nearer or farther (into the volume below distance 100).
function attachLightDrag() {
  let last = null;
  const active = (e) => !lightPanel.hidden && (light.drag.checked || e.shiftKey);
  canvas.addEventListener('pointerdown', (e) => {
    if (!active(e)) return;
    e.stopImmediatePropagation();
    canvas.setPointerCapture(e.pointerId);
    last = { id: e.pointerId, x: e.clientX, y: e.clientY };
  }, { capture: true });
  canvas.addEventListener('pointermove', (e) => {
    if (!last || e.pointerId !== last.id) return;
    e.stopImmediatePropagation();
    const dx = e.clientX - last.x;
    const dy = e.clientY - last.y;
    last = { id: e.pointerId, x: e.clientX, y: e.clientY };
    const azimuth = ((Number(light.azimuth.value) - dx * 0.5 + 540) % 360) - 180;
    light.azimuth.value = String(azimuth);
    light.elevation.value = String(Math.max(-90, Math.min(90, Number(light.elevation.value) - dy * 0.5)));
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
    if (!active(e) || light.kind.value === 'directional') return;
    e.preventDefault();
    e.stopImmediatePropagation();
    light.distance.value = String(Number(light.distance.value) * Math.exp(e.deltaY * 0.001));
    requestFrame();
  }, { capture: true, passive: false });
}

// Sends the view; the server renders what it needs (the argument, whether the
// user is dragging, is no longer needed: the server sees the messages come).
function requestFrame() {
  if (!dataset || !stream) return;
  const { size, dpr } = viewport();
  stream.update({
    dataset: dataset.id,
    ...camera.params(),
    ...size,
    ...(customTf ? { tf: customTf } : { preset: presetSelect.value }),
    shading: shadingSelect.value,
    compositing: compositingSelect.value,
    proj: projectionSelect.value,
    reduction: reductionSelect.value,
    ...clipParam(),
    ...lightParams(),
  }, dpr);
}

async function start() {
  resizeCanvas();
  let datasets;
  try {
    const response = await fetch('/api/datasets');
    datasets = await response.json();
  } catch (e) {
    errorBox.textContent = `cannot load the dataset list: ${e.message}`;
    errorBox.hidden = false;
    return;
  }
  // The dataset picker: the server's datasets, the default (first) chosen.
  const datasetSelect = document.getElementById('dataset');
  for (const d of datasets) {
    const [nx, ny, nz] = d.dims;
    datasetSelect.add(new Option(`${d.name} ${nx}×${ny}×${nz}`, d.id));
  }
  const choose = (id) => {
    dataset = datasets.find((d) => d.id === id) || datasets[0];
    presetSelect.replaceChildren();
    for (const preset of dataset.presets) {
      const option = new Option(preset.name, preset.name);
      option.title = preset.description;
      presetSelect.add(option);
    }
    presetSelect.value = dataset.default_preset;
    loadPreset();
  };
  choose(datasets[0].id);
  datasetSelect.addEventListener('change', () => {
    choose(datasetSelect.value);
    camera.reset();
    requestFrame(false);
  });
  stream = new ViewStream(drawFrame, showError, () => {});

  attachLightDrag();
  attachGestures(canvas, camera, requestFrame);
  presetSelect.addEventListener('change', () => {
    loadPreset();
    requestFrame(false);
  });
  for (const select of [shadingSelect, compositingSelect, projectionSelect, reductionSelect]) {
    select.addEventListener('change', () => requestFrame(false));
  }
  for (const slider of clipSliders.flat()) {
    slider.addEventListener('input', () => requestFrame(true));
  }
  shadingSelect.addEventListener('change', showLightPanel);
  showLightPanel();
  for (const input of Object.values(light)) {
    if (input !== light.drag) input.addEventListener('change', () => requestFrame(false));
  }
  light.kind.addEventListener('change', showLightPanel);
  document.getElementById('reset').addEventListener('click', () => {
    camera.reset();
    requestFrame(false);
  });
  window.addEventListener('resize', () => {
    resizeCanvas();
    requestFrame(true);
  });
  requestFrame(false);
}

start();
