// voxserve's web client: shows frames rendered on the server and sends the
// camera and transfer-function choices back. No build step; plain ES modules.

import { OrbitCamera, attachGestures } from './camera.js';
import { FrameFetcher } from './frames.js';

// While the user drags, frames are rendered at this fraction of the full
// resolution, so they come back fast; the full frame follows once idle.
const INTERACTIVE_SCALE = 0.5;
const IDLE_MS = 250;
// The full frame's longest side, in device pixels (software GPUs are slow).
const MAX_EDGE = 1536;

const canvas = document.getElementById('view');
const context = canvas.getContext('2d');
const presetSelect = document.getElementById('preset');
const shadingSelect = document.getElementById('shading');
const projectionSelect = document.getElementById('projection');
const reductionSelect = document.getElementById('reduction');
const clipBox = document.getElementById('clip');
const errorBox = document.getElementById('error');
const fidelity = document.getElementById('fidelity');

const camera = new OrbitCamera();
let dataset = null;
let idleTimer = 0;

const fetcher = new FrameFetcher(
  (bitmap, info) => {
    errorBox.hidden = true;
    context.imageSmoothingEnabled = true;
    context.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
    bitmap.close();
    fidelity.textContent =
      `${info.width}×${info.height} · reduction ${info.reduction.toFixed(1)}:1 · ` +
      `blocks per level ${info.levels} · render ${info.renderMs.toFixed(0)} ms · ` +
      `encode ${info.encodeMs.toFixed(0)} ms · round trip ${info.roundTripMs.toFixed(0)} ms`;
  },
  (message) => {
    errorBox.textContent = message;
    errorBox.hidden = false;
  },
);

function resizeCanvas() {
  const dpr = window.devicePixelRatio || 1;
  canvas.width = Math.max(1, Math.round(canvas.clientWidth * dpr));
  canvas.height = Math.max(1, Math.round(canvas.clientHeight * dpr));
}

// The image size to ask for: the canvas, capped, scaled while interacting.
function frameSize(interacting) {
  const cap = Math.min(1, MAX_EDGE / Math.max(canvas.width, canvas.height));
  const scale = cap * (interacting ? INTERACTIVE_SCALE : 1);
  return {
    w: Math.max(1, Math.round(canvas.width * scale)),
    h: Math.max(1, Math.round(canvas.height * scale)),
  };
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

// The clip box parameter, or nothing when the whole volume shows. Keeps each
// axis's min below its max.
function clipParam() {
  const lo = [];
  const hi = [];
  for (const [min, max] of clipSliders) {
    const a = Math.min(Number(min.value), 999);
    const b = Math.max(Number(max.value), a + 1);
    lo.push(a / 1000);
    hi.push(b / 1000);
  }
  const whole = lo.every((v) => v === 0) && hi.every((v) => v === 1);
  return whole ? {} : { clip: [...lo, ...hi].join(',') };
}

function requestFrame(interacting) {
  if (!dataset) return;
  fetcher.request({
    dataset: dataset.id,
    ...camera.params(),
    ...frameSize(interacting),
    preset: presetSelect.value,
    shading: shadingSelect.value,
    proj: projectionSelect.value,
    reduction: reductionSelect.value,
    ...clipParam(),
  });
  clearTimeout(idleTimer);
  if (interacting) idleTimer = setTimeout(() => requestFrame(false), IDLE_MS);
}

async function start() {
  resizeCanvas();
  try {
    const response = await fetch('/api/datasets');
    const datasets = await response.json();
    dataset = datasets[0];
  } catch (e) {
    errorBox.textContent = `cannot load the dataset list: ${e.message}`;
    errorBox.hidden = false;
    return;
  }
  const [nx, ny, nz] = dataset.dims;
  document.getElementById('dataset').textContent = `${dataset.name} ${nx}×${ny}×${nz}`;
  for (const preset of dataset.presets) {
    const option = new Option(preset.name, preset.name);
    option.title = preset.description;
    presetSelect.add(option);
  }
  presetSelect.value = dataset.default_preset;

  attachGestures(canvas, camera, requestFrame);
  presetSelect.addEventListener('change', () => requestFrame(false));
  for (const select of [shadingSelect, projectionSelect, reductionSelect]) {
    select.addEventListener('change', () => requestFrame(false));
  }
  for (const slider of clipSliders.flat()) {
    slider.addEventListener('input', () => requestFrame(true));
  }
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
