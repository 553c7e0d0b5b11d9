// Slice views (multiplanar reformatting) beside the 3D view: axial, coronal
// and sagittal planes through a crosshair, rendered by the server from the
// same bricks (server/src/protocol.rs: `view` messages with `pane`, `slice`
// messages saying where each frame lies, `probe` for the value under the
// cursor). This module holds what the client owns of them: the crosshair,
// the window, the slab, each view's zoom and pan, the measurements; the
// server's `slice` settings (GET /api/settings `slice`) give every range and
// default, and each frame's placement maps the cursor to the patient.
//
// Gestures on a slice view: the wheel, arrows and Page keys (or a one-finger
// drag on touch screens) scroll through the slices; a click or tap puts the
// crosshair there (the other views follow); a drag sets the window (across:
// width, up and down: level); a drag that starts on a crosshair line away
// from its centre turns the other two planes about this view's normal
// (oblique views: each view keeps its own orientation, a quaternion); right, middle or Ctrl drag pans, Ctrl+wheel
// or a pinch zooms towards the cursor; + and − zoom; R resets. In measure
// mode clicks place the points of a distance (2) or an angle (3), listed
// and drawn on the slice they lie in.

import { spread } from './camera.js';

export const PLANES = ['axial', 'coronal', 'sagittal'];
const TITLES = { axial: 'Axial', coronal: 'Coronal', sagittal: 'Sagittal' };
// The planes' colours (their crosshair lines in the other views).
const COLOURS = { axial: '#f55', coronal: '#4d4', sagittal: '#fd4' };
// Wheel travel (pixels: a mouse's notch) per slice, touch travel per
// slice, window/level drag gain.
const WHEEL_PER_SLICE = 100;
const TOUCH_PER_SLICE = 10;
const WINDOW_PER_PIXEL = 1 / 250;
const KEY_ZOOM = 1.15;
const PAGE_SLICES = 10;
const SVG = 'http://www.w3.org/2000/svg';

const sub = (a, b) => a.map((v, i) => v - b[i]);
const add = (a, b) => a.map((v, i) => v + b[i]);
const scale = (a, k) => a.map((v) => v * k);
const dot = (a, b) => a.reduce((s, v, i) => s + v * b[i], 0);
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const length = (a) => Math.hypot(...a);
// Quaternions [w, x, y, z]: a turn of `angle` radians about unit `axis`, the
// product a·b (b first, then a), and the text form the `orient` setting takes.
const turn = (axis, angle) => [Math.cos(angle / 2), ...scale(axis, Math.sin(angle / 2))];
function multiply([aw, ax, ay, az], [bw, bx, by, bz]) {
  const q = [
    aw * bw - ax * bx - ay * by - az * bz,
    aw * bx + ax * bw + ay * bz - az * by,
    aw * by - ax * bz + ay * bw + az * bx,
    aw * bz + ax * by - ay * bx + az * bw,
  ];
  return scale(q, 1 / length(q));
}
const quatText = (q) => q.map((v) => round(v, 6)).join(',');
// How near a crosshair line (CSS px) a drag turns it, and how far from its centre.
const LINE_GRAB = 6;
const LINE_CENTRE = 24;

// The patient's directions (LPS: +x left, +y posterior, +z superior) as the
// letter or two a direction is nearest to (two when it is oblique).
const DIRECTIONS = [['L', 'R'], ['P', 'A'], ['S', 'I']];
export function directionLetters(v) {
  const order = [0, 1, 2].sort((a, b) => Math.abs(v[b]) - Math.abs(v[a]));
  const letter = (axis) => DIRECTIONS[axis][v[axis] >= 0 ? 0 : 1];
  const first = letter(order[0]);
  return Math.abs(v[order[1]]) > 0.38 ? first + letter(order[1]) : first;
}

// The longest 1, 2 or 5 × 10^k mm (k from −3 to 5) at most `maxPixels`
// long at `mmPerPixel`; null when even 1 µm is longer.
export function scaleBarMm(mmPerPixel, maxPixels) {
  let best = null;
  for (let k = -3; k <= 5; k += 1) {
    for (const step of [1, 2, 5]) {
      const mm = step * 10 ** k;
      if (mm / mmPerPixel <= maxPixels) best = mm;
    }
  }
  return best;
}

// Distance between two model points (mm), and the angle at `b` (degrees).
export function distanceMm(a, b) {
  return length(sub(a, b));
}
export function angleDeg(a, b, c) {
  const u = sub(a, b);
  const v = sub(c, b);
  const cos = dot(u, v) / Math.max(1e-9, length(u) * length(v));
  return (Math.acos(Math.max(-1, Math.min(1, cos))) * 180) / Math.PI;
}

export class SliceViews {
  // `schema`: the slice settings (settings.js Schema of GET /api/settings
  // `slice`); `stream`: the ViewStream; `onChange()` runs after a change of
  // what the slice views show (the crosshair, the window, …); `onMeasure()`
  // after the measurements changed; `onError(message)` for what to tell.
  constructor(schema, stream, { onChange, onMeasure, onError }) {
    this.schema = schema;
    this.stream = stream;
    this.onChange = onChange;
    this.onMeasure = onMeasure;
    this.onError = onError;
    this.dataset = null;
    this.measure = 'off';
    this.measurements = [];
    this.pendingPoints = null;
    this.panes = {};
    for (const plane of PLANES) this.panes[plane] = this.buildPane(plane);
    this.reset();
  }

  // A slice view's elements: the frame's canvas, an overlay (crosshair,
  // measurements), its name, orientation letters, the value under the
  // cursor and a progress mark.
  buildPane(plane) {
    const section = document.createElement('section');
    section.className = 'pane slice-pane';
    section.dataset.pane = plane;
    section.hidden = true;
    section.tabIndex = 0;
    section.setAttribute('aria-label', `${TITLES[plane]} slice: wheel, arrows or Page keys scroll; ` +
      'click sets the crosshair; drag sets the window; right-drag pans; + and − zoom; R resets');
    const canvas = document.createElement('canvas');
    const overlay = document.createElementNS(SVG, 'svg');
    overlay.classList.add('pane-overlay');
    const name = document.createElement('span');
    name.className = 'pane-name';
    name.style.color = COLOURS[plane];
    const info = document.createElement('span');
    info.className = 'pane-info';
    const probe = document.createElement('span');
    probe.className = 'pane-probe';
    const busy = document.createElement('span');
    busy.className = 'pane-busy';
    const letters = {};
    for (const edge of ['top', 'bottom', 'left', 'right']) {
      letters[edge] = document.createElement('span');
      letters[edge].className = `pane-orient pane-orient-${edge}`;
    }
    section.append(canvas, overlay, name, info, probe, busy, ...Object.values(letters));
    // After the 3D view in the tab order, before the toolbar.
    document.getElementById('toolbar').before(section);
    const pane = {
      plane, section, canvas, context: canvas.getContext('2d'), overlay, name, info, probe, busy, letters,
      zoom: 1, px: 0, py: 0, placement: null, frame: null, latest: false,
    };
    this.attachGestures(pane);
    return pane;
  }

  // A new dataset: the crosshair at its centre, its default window, no measurements.
  setDataset(dataset) {
    this.dataset = dataset;
    this.reset();
    this.measurements = [];
    this.onMeasure();
  }

  // Everything back to the schema's defaults: the crosshair at the volume's
  // centre, the dataset's default window, no slab, each view fitted.
  reset() {
    const d = (name) => this.schema.default(name);
    this.crosshair = [d('cx'), d('cy'), d('cz')];
    this.orients = Object.fromEntries(PLANES.map((p) => [p, d('orient').split(',').map(Number)]));
    this.window = null;
    this.slab = d('slab');
    this.slabMode = d('slab_mode');
    for (const pane of Object.values(this.panes)) {
      pane.zoom = d('zoom');
      pane.px = d('px');
      pane.py = d('py');
    }
    this.pendingPoints = null;
  }

  // Shows the views of `shown` at their rectangles (CSS pixels), hides the others.
  place(rects, dpr) {
    for (const [plane, pane] of Object.entries(this.panes)) {
      const rect = rects[plane];
      pane.section.hidden = !rect;
      if (!rect) continue;
      Object.assign(pane.section.style, {
        left: `${rect.left}px`, top: `${rect.top}px`, width: `${rect.width}px`, height: `${rect.height}px`,
      });
      pane.canvas.width = Math.max(1, Math.round(rect.width * dpr));
      pane.canvas.height = Math.max(1, Math.round(rect.height * dpr));
      pane.overlay.setAttribute('viewBox', `0 0 ${rect.width} ${rect.height}`);
      this.drawOverlay(pane);
    }
  }

  // The settings of each shown slice view, as its `view` messages set them.
  views() {
    const out = {};
    for (const [plane, pane] of Object.entries(this.panes)) {
      if (pane.section.hidden) continue;
      const view = {
        w: Math.max(1, Math.round(pane.section.clientWidth)),
        h: Math.max(1, Math.round(pane.section.clientHeight)),
        cx: round(this.crosshair[0]), cy: round(this.crosshair[1]), cz: round(this.crosshair[2]),
        zoom: round(pane.zoom, 3), px: round(pane.px), py: round(pane.py),
        slab: this.slab, slab_mode: this.slabMode,
      };
      const orient = quatText(this.orients[plane]);
      if (orient !== this.schema.default('orient')) view.orient = orient;
      if (this.window) view.window = `${round(this.window.centre)},${round(this.window.width)}`;
      out[plane] = view;
    }
    return out;
  }

  // The window slices are drawn through: the one set, else the server's
  // (from the last frame), else the dataset's default.
  currentWindow() {
    if (this.window) return this.window;
    for (const pane of Object.values(this.panes)) {
      if (pane.serverWindow) return pane.serverWindow;
    }
    const w = this.dataset.default_window;
    return { centre: w.centre, width: w.width };
  }

  // Sets the window (null: the dataset's default).
  setWindow(window) {
    this.window = window;
    this.onChange();
  }

  // Draws a slice frame (`info` from stream.js, with the placement).
  draw(bitmap, info) {
    const pane = this.panes[info.pane];
    if (!pane) {
      bitmap.close();
      return;
    }
    pane.context.imageSmoothingEnabled = true;
    pane.context.drawImage(bitmap, 0, 0, pane.canvas.width, pane.canvas.height);
    bitmap.close();
    if (info.placement) {
      pane.placement = info.placement.placement;
      pane.serverWindow = { centre: info.placement.window[0], width: info.placement.window[1] };
    }
    pane.frame = { width: info.width, height: info.height };
    const done = info.latest && info.lossless && info.converged && !info.pendingBlocks;
    pane.busy.classList.toggle('on', !done);
    pane.section.dataset.frames = String(Number(pane.section.dataset.frames || 0) + 1);
    pane.section.dataset.lossless = String(info.lossless && info.latest);
    pane.section.title = `${info.width}×${info.height} ${info.lossless ? 'lossless' : 'JPEG'} · ` +
      `render ${info.renderMs.toFixed(0)} ms · encode ${info.encodeMs.toFixed(0)} ms` +
      (Number.isNaN(info.latencyMs) ? '' : ` · latency ${info.latencyMs.toFixed(0)} ms`) +
      (info.pendingBlocks ? ` · loading ${info.pendingBlocks} blocks` : '');
    this.drawOverlay(pane);
  }

  // A view's spinner turns until its next frame is in.
  markBusy(planes) {
    for (const plane of planes) this.panes[plane]?.busy.classList.add('on');
  }

  // CSS pixel (x, y) of a view → model mm, through its last frame's
  // placement, on the plane through the crosshair now (the frame may still
  // show the slice before the last scroll).
  toModel(pane, x, y) {
    const p = pane.placement;
    if (!p || !pane.frame) return null;
    const fx = (x * pane.frame.width) / pane.section.clientWidth - 0.5;
    const fy = (y * pane.frame.height) / pane.section.clientHeight - 0.5;
    const at = add(add(p.corner, scale(p.right, fx)), scale(p.down, fy));
    return add(at, scale(p.normal, dot(sub(this.crosshair, at), p.normal)));
  }

  // Model mm → CSS pixel of a view (its plane's projection).
  toScreen(pane, point) {
    const p = pane.placement;
    if (!p || !pane.frame) return null;
    const d = sub(point, p.corner);
    const fx = dot(d, p.right) / dot(p.right, p.right) + 0.5;
    const fy = dot(d, p.down) / dot(p.down, p.down) + 0.5;
    return [(fx * pane.section.clientWidth) / pane.frame.width, (fy * pane.section.clientHeight) / pane.frame.height];
  }

  // Millimetres per CSS pixel of a view.
  mmPerPixel(pane) {
    if (!pane.placement || !pane.frame) return 0;
    return (length(pane.placement.right) * pane.frame.width) / Math.max(1, pane.section.clientWidth);
  }

  // The spacing between slices along a view's normal (mm): the voxel's
  // extent along it.
  sliceStep(pane) {
    const n = pane.placement ? pane.placement.normal : null;
    const spacing = this.dataset.spacing;
    if (!n) return Math.min(...spacing);
    const columns = this.dataset.direction;
    const k = Math.hypot(...columns.map((d, j) => dot(n, d) / spacing[j]));
    return k > 0 ? 1 / k : Math.min(...spacing);
  }

  // Moves the crosshair `slices` slices along a view's normal (positive:
  // away from the viewer), within the volume.
  scroll(pane, slices) {
    if (!pane.placement) return;
    const n = pane.placement.normal;
    const step = this.sliceStep(pane);
    const along = dot(this.crosshair, n) - slices * step;
    const limit = this.dataset.radius_mm;
    const clamped = Math.max(-limit, Math.min(limit, along));
    this.crosshair = add(this.crosshair, scale(n, clamped - dot(this.crosshair, n)));
    this.onChange();
  }

  // Puts the crosshair at model point `at` (a click in a slice, a pick in 3D).
  moveCrosshair(at) {
    this.crosshair = at.map((v) => round(v));
    this.onChange();
  }

  zoomAt(pane, factor, x, y) {
    const max = this.schema.get('zoom').max;
    const min = this.schema.get('zoom').min;
    const before = this.toModel(pane, x, y);
    const zoom = Math.max(min, Math.min(max, pane.zoom * factor));
    if (before && pane.placement) {
      // The point under the cursor stays: the image centre moves towards it.
      const applied = zoom / pane.zoom;
      const w = pane.section.clientWidth;
      const h = pane.section.clientHeight;
      const mm = this.mmPerPixel(pane);
      const ox = (x - w / 2) * mm;
      const oy = (h / 2 - y) * mm;
      pane.px += ox * (1 - 1 / applied);
      pane.py += oy * (1 - 1 / applied);
    }
    pane.zoom = zoom;
    this.onChange();
  }

  // Turns the other two planes by `angle` radians about a view's normal
  // (counter-clockwise as the view shows it); this view's plane stays.
  rotate(pane, angle) {
    if (!pane.placement) return;
    const r = turn(pane.placement.normal, angle);
    for (const plane of PLANES) {
      if (plane !== pane.plane) this.orients[plane] = multiply(r, this.orients[plane]);
    }
    this.onChange();
  }

  // Whether CSS pixel (x, y) of a view lies on one of its crosshair lines,
  // away from the centre (where a drag turns them).
  onLine(pane, x, y) {
    if (!pane.lines || !pane.centre) return false;
    const [cx, cy] = pane.centre;
    const away = Math.hypot(x - cx, y - cy);
    if (away < LINE_CENTRE) return false;
    return pane.lines.some(([sx, sy]) => Math.abs((x - cx) * sy - (y - cy) * sx) <= LINE_GRAB);
  }

  pan(pane, dx, dy) {
    const mm = this.mmPerPixel(pane);
    pane.px -= dx * mm;
    pane.py += dy * mm;
    this.onChange();
  }

  // Window/level drag: across changes the width, up and down the level.
  dragWindow(dx, dy) {
    const w = this.currentWindow();
    const width = Math.max(1e-3, w.width * Math.exp(dx * WINDOW_PER_PIXEL * 2));
    const centre = w.centre - dy * w.width * WINDOW_PER_PIXEL;
    this.setWindow({ centre, width });
  }

  // The value under CSS pixel (x, y) of a view, asked of the server (one
  // probe in flight per view; the last position wins).
  async hover(pane, x, y) {
    const at = this.toModel(pane, x, y);
    if (!at) return;
    pane.hoverAt = at;
    if (pane.probing) return;
    pane.probing = true;
    // Whether an answer is still to come (what the readout shows may be older).
    pane.probe.dataset.busy = '1';
    while (pane.hoverAt) {
      const asked = pane.hoverAt;
      pane.hoverAt = null;
      const answer = await this.stream.ask('probe', { at: asked.map((v) => round(v, 3)) });
      if (!answer) break;
      const v = answer.voxel;
      pane.probe.textContent = v
        ? `${formatValue(v.value)}${answer.unit ? ` ${answer.unit}` : ''} · voxel ${v.index.join(', ')}`
        : 'outside the volume';
      pane.probe.dataset.value = v ? String(v.value) : '';
      pane.probe.dataset.index = v ? v.index.join(',') : '';
    }
    pane.probing = false;
    pane.probe.dataset.busy = '';
  }

  // A click at CSS pixel (x, y) of a view: a measurement point in measure
  // mode, else the crosshair.
  click(pane, x, y) {
    const at = this.toModel(pane, x, y);
    if (!at) return;
    // The value there too: on a touch screen a tap is the only way to point.
    this.hover(pane, x, y);
    if (this.measure === 'off') {
      this.moveCrosshair(at);
      return;
    }
    const needed = this.measure === 'angle' ? 3 : 2;
    if (!this.pendingPoints || this.pendingPoints.plane !== pane.plane) {
      this.pendingPoints = { plane: pane.plane, kind: this.measure, points: [] };
    }
    this.pendingPoints.points.push(at);
    if (this.pendingPoints.points.length === needed) {
      const { points, kind, plane } = this.pendingPoints;
      const value = kind === 'angle' ? angleDeg(...points) : distanceMm(...points);
      this.measurements.push({ plane, kind, points, value });
      this.pendingPoints = null;
      this.onMeasure();
    }
    this.drawOverlay(pane);
  }

  // Every measurement in words, for the list.
  describe(m) {
    return m.kind === 'angle' ? `${m.value.toFixed(1)}°` : `${m.value.toFixed(1)} mm`;
  }

  clearMeasurements() {
    this.measurements = [];
    this.pendingPoints = null;
    this.onMeasure();
    this.redraw();
  }

  redraw() {
    for (const pane of Object.values(this.panes)) if (!pane.section.hidden) this.drawOverlay(pane);
  }

  // The volume's centre in patient coordinates (LPS mm; model space is
  // patient space shifted to put it at 0).
  patientCentre() {
    const d = this.dataset;
    return [0, 1, 2].map((r) => d.origin[r] +
      [0, 1, 2].reduce((s, a) => s + d.direction[a][r] * d.spacing[a] * (d.dims[a] - 1) / 2, 0));
  }

  // Whether model point `p` lies in a view's current plane (within half a slice).
  inPlane(pane, p) {
    const n = pane.placement.normal;
    return Math.abs(dot(sub(p, this.crosshair), n)) <= this.sliceStep(pane) / 2 + 1e-3;
  }

  // The crosshair's lines (the other planes through it), the measurements
  // in this plane, the orientation letters and the view's caption.
  drawOverlay(pane) {
    const svg = pane.overlay;
    svg.replaceChildren();
    pane.name.textContent = TITLES[pane.plane];
    const p = pane.placement;
    if (!p || !this.dataset) return;
    const right = scale(p.right, 1 / length(p.right));
    const up = scale(p.down, -1 / length(p.down));
    const neg = (v) => scale(v, -1);
    const edges = { right, left: neg(right), top: up, bottom: neg(up) };
    for (const [edge, v] of Object.entries(edges)) pane.letters[edge].textContent = directionLetters(v);
    // The slice's place in the patient's coordinates (the scanner's, from
    // the dataset's origin), along the way scrolling goes: "S 74.4 mm".
    const deeper = neg(p.normal);
    const along = dot(add(this.crosshair, this.patientCentre()), deeper);
    const side = directionLetters(along >= 0 ? deeper : p.normal);
    const w = this.currentWindow();
    const slab = this.slab > 0 ? ` · ${this.slabMode} ${round(this.slab, 1)} mm` : '';
    pane.info.textContent = `${side} ${Math.abs(along).toFixed(1)} mm · W ${round(w.width, 0)} L ${round(w.centre, 0)}${slab}`;
    const centre = this.toScreen(pane, this.crosshair);
    pane.centre = centre;
    pane.lines = [];
    if (centre) {
      PLANES.forEach((other, i) => {
        if (other === pane.plane) return;
        const d = cross(p.normal, p.normals[i]);
        const sx = dot(d, right);
        const sy = -dot(d, up);
        const len = Math.hypot(sx, sy);
        if (len < 1e-6) return;
        pane.lines.push([sx / len, sy / len]);
        const far = 1e4 / len;
        const line = document.createElementNS(SVG, 'line');
        line.setAttribute('x1', centre[0] - sx * far);
        line.setAttribute('y1', centre[1] - sy * far);
        line.setAttribute('x2', centre[0] + sx * far);
        line.setAttribute('y2', centre[1] + sy * far);
        line.setAttribute('stroke', COLOURS[other]);
        line.classList.add('crosshair', `crosshair-${other}`);
        svg.append(line);
      });
      svg.dataset.crosshair = centre.map((v) => v.toFixed(1)).join(',');
    }
    // A scale bar: the longest 1, 2 or 5 × 10^k mm within a quarter of the width.
    const mm = this.mmPerPixel(pane);
    const width = pane.section.clientWidth;
    const height = pane.section.clientHeight;
    const bar = mm > 0 ? scaleBarMm(mm, width / 4) : null;
    if (bar) {
      const x1 = width - 22;
      const x0 = x1 - bar / mm;
      const line = document.createElementNS(SVG, 'polyline');
      line.setAttribute('points', `${x0},${height - 24} ${x0},${height - 20} ${x1},${height - 20} ${x1},${height - 24}`);
      line.classList.add('scale-bar');
      const label = document.createElementNS(SVG, 'text');
      label.setAttribute('x', (x0 + x1) / 2);
      label.setAttribute('y', height - 27);
      label.setAttribute('text-anchor', 'middle');
      label.textContent = `${Number(bar.toPrecision(2))} mm`;
      label.classList.add('scale-label');
      svg.append(line, label);
      svg.dataset.scaleMm = String(bar);
    }
    const shapes = [...this.measurements];
    if (this.pendingPoints && this.pendingPoints.plane === pane.plane) shapes.push(this.pendingPoints);
    for (const m of shapes) {
      if (m.plane !== pane.plane || !m.points.every((q) => this.inPlane(pane, q))) continue;
      const points = m.points.map((q) => this.toScreen(pane, q));
      const line = document.createElementNS(SVG, 'polyline');
      line.setAttribute('points', points.map((q) => q.join(',')).join(' '));
      line.classList.add('measure');
      svg.append(line);
      for (const q of points) {
        const dotMark = document.createElementNS(SVG, 'circle');
        dotMark.setAttribute('cx', q[0]);
        dotMark.setAttribute('cy', q[1]);
        dotMark.setAttribute('r', 3);
        dotMark.classList.add('measure-point');
        svg.append(dotMark);
      }
      if (m.value !== undefined) {
        const label = document.createElementNS(SVG, 'text');
        const at = points[points.length - 1];
        label.setAttribute('x', at[0] + 6);
        label.setAttribute('y', at[1] - 6);
        label.textContent = this.describe(m);
        label.classList.add('measure-label');
        svg.append(label);
      }
    }
  }

  attachGestures(pane) {
    const el = pane.section;
    const pointers = new Map();
    let gesture = null;
    let pinch = 0;
    let wheel = 0;
    const local = (e) => {
      const r = el.getBoundingClientRect();
      return [e.clientX - r.left, e.clientY - r.top];
    };
    el.addEventListener('contextmenu', (e) => e.preventDefault());
    el.addEventListener('pointerdown', (e) => {
      el.setPointerCapture(e.pointerId);
      el.focus({ preventScroll: true });
      const [x, y] = local(e);
      pointers.set(e.pointerId, { x, y });
      const pan = e.button === 1 || e.button === 2 || (e.button === 0 && (e.ctrlKey || e.metaKey));
      let kind = pan ? 'pan' : e.pointerType === 'touch' ? 'scroll' : 'window';
      if (!pan && pointers.size === 1 && this.onLine(pane, x, y)) kind = 'rotate';
      gesture = { kind, x0: x, y0: y, moved: false, travel: 0 };
      pinch = spread(pointers);
    });
    el.addEventListener('pointermove', (e) => {
      const [x, y] = local(e);
      const last = pointers.get(e.pointerId);
      if (!last) {
        if (e.pointerType !== 'touch') this.hover(pane, x, y);
        return;
      }
      const dx = x - last.x;
      const dy = y - last.y;
      pointers.set(e.pointerId, { x, y });
      if (!gesture) return;
      if (Math.hypot(x - gesture.x0, y - gesture.y0) > 4) gesture.moved = true;
      if (pointers.size === 2) {
        const d = spread(pointers);
        if (pinch > 0 && d > 0) this.zoomAt(pane, d / pinch, x, y);
        pinch = d;
        gesture.kind = 'pinch';
        return;
      }
      if (!gesture.moved) return;
      if (gesture.kind === 'rotate' && pane.centre) {
        // The cursor's turn about the crosshair (screen y points down).
        const [cx, cy] = pane.centre;
        const before = Math.atan2(last.y - cy, last.x - cx);
        const now = Math.atan2(y - cy, x - cx);
        let angle = now - before;
        if (angle > Math.PI) angle -= 2 * Math.PI;
        if (angle < -Math.PI) angle += 2 * Math.PI;
        this.rotate(pane, -angle);
      } else if (gesture.kind === 'pan') this.pan(pane, dx, dy);
      else if (gesture.kind === 'window') this.dragWindow(dx, dy);
      else if (gesture.kind === 'scroll') {
        gesture.travel -= dy;
        const slices = Math.trunc(gesture.travel / TOUCH_PER_SLICE);
        if (slices) {
          gesture.travel -= slices * TOUCH_PER_SLICE;
          this.scroll(pane, slices);
        }
      }
    });
    const end = (e) => {
      pointers.delete(e.pointerId);
      const clicked = gesture && !gesture.moved && pointers.size === 0;
      if (clicked && gesture.kind !== 'pan' && gesture.kind !== 'pinch') {
        this.click(pane, ...local(e));
      }
      if (pointers.size === 0) gesture = null;
      pinch = spread(pointers);
    };
    el.addEventListener('pointerup', end);
    el.addEventListener('pointercancel', (e) => {
      pointers.delete(e.pointerId);
      gesture = null;
    });
    el.addEventListener('wheel', (e) => {
      e.preventDefault();
      const [x, y] = local(e);
      if (e.ctrlKey || e.metaKey) {
        this.zoomAt(pane, Math.exp(-e.deltaY * 0.001), x, y);
        return;
      }
      // Lines (Firefox) count as about 33 pixels.
      wheel += e.deltaMode === 1 ? e.deltaY * 33 : e.deltaY;
      // Wheel up (away from the user) goes deeper, as the Up and Page Up keys.
      const slices = Math.trunc(wheel / WHEEL_PER_SLICE);
      if (slices) {
        wheel -= slices * WHEEL_PER_SLICE;
        this.scroll(pane, -slices);
      }
    }, { passive: false });
    el.addEventListener('keydown', (e) => {
      if (e.altKey || e.ctrlKey || e.metaKey) return;
      const steps = { ArrowUp: 1, ArrowDown: -1, PageUp: PAGE_SLICES, PageDown: -PAGE_SLICES };
      const w = el.clientWidth / 2;
      const h = el.clientHeight / 2;
      if (e.key in steps) this.scroll(pane, steps[e.key]);
      else if (e.key === '+' || e.key === '=') this.zoomAt(pane, KEY_ZOOM, w, h);
      else if (e.key === '-' || e.key === '_') this.zoomAt(pane, 1 / KEY_ZOOM, w, h);
      else return;
      e.preventDefault();
      e.stopPropagation();
    });
  }

  // The slice state for the address's hash (names of their own: `cx`, `cy`,
  // `cz`, `swindow`, `slab`, `slab_mode`, `<plane>_zoom`, `<plane>_orient`, …).
  linkParams(params) {
    const d = (name) => this.schema.default(name);
    const put = (name, value, fallback) => {
      if (value !== fallback) params.set(name, String(value));
    };
    put('cx', round(this.crosshair[0]), d('cx'));
    put('cy', round(this.crosshair[1]), d('cy'));
    put('cz', round(this.crosshair[2]), d('cz'));
    if (this.window) params.set('swindow', `${round(this.window.centre)},${round(this.window.width)}`);
    put('slab', this.slab, d('slab'));
    put('slab_mode', this.slabMode, d('slab_mode'));
    for (const [plane, pane] of Object.entries(this.panes)) {
      put(`${plane}_zoom`, round(pane.zoom, 3), d('zoom'));
      put(`${plane}_px`, round(pane.px), d('px'));
      put(`${plane}_py`, round(pane.py), d('py'));
      put(`${plane}_orient`, quatText(this.orients[plane]), d('orient'));
    }
  }

  applyLink(params) {
    const number = (name, fallback) => (params.get(name) !== null ? Number(params.get(name)) : fallback);
    this.crosshair = ['cx', 'cy', 'cz'].map((name, i) => number(name, this.crosshair[i]));
    if (params.get('swindow') !== null) {
      const [centre, width] = params.get('swindow').split(',').map(Number);
      this.window = { centre, width };
    }
    this.slab = number('slab', this.slab);
    if (params.get('slab_mode') !== null) this.slabMode = params.get('slab_mode');
    for (const [plane, pane] of Object.entries(this.panes)) {
      pane.zoom = number(`${plane}_zoom`, pane.zoom);
      pane.px = number(`${plane}_px`, pane.px);
      pane.py = number(`${plane}_py`, pane.py);
      const orient = params.get(`${plane}_orient`);
      if (orient !== null) this.orients[plane] = orient.split(',').map(Number);
    }
  }
}

function round(v, digits = 2) {
  return Number(v.toFixed(digits));
}

function formatValue(v) {
  return Number.isInteger(v) ? String(v) : String(Number(v.toPrecision(5)));
}
