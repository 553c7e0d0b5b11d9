// The transfer-function editor: opacity control points drawn over the
// dataset's histogram (log counts), each with its colour, and a colour bar.
//
// - drag a point to move it (value across, opacity up);
// - double-click empty space to add a point, double-click a point to remove it
//   (two stay at least);
// - click a point to select it; the colour input sets its colour;
// - drag empty space for window/level: across moves every point (level), up
//   and down widens or narrows their spread about the middle (window).
//
// The text form is the `tf` view setting's (GET /api/settings says what it
// takes): `VALUE:RRGGBB:OPACITY,…` in physical units.

const HANDLE = 6;
// Window/level keeps the middle of what the points show on the histogram's
// value range, and their spread between these shares of the range wide: a
// drag can narrow, widen or move the window, never push it off the histogram.
const MIN_SPREAD = 0.005;
const MAX_SPREAD = 20;

// The span of values `points` show: from the last point of no opacity before
// the first with some, to the first of no opacity after the last with some
// (as the server's `TransferFunction::shown_span`); null when none shows.
export function shownSpan(points) {
  const first = points.findIndex((p) => p.opacity > 0);
  if (first < 0) return null;
  const last = points.length - 1 - [...points].reverse().findIndex((p) => p.opacity > 0);
  return [points[Math.max(0, first - 1)].value, points[Math.min(points.length - 1, last + 1)].value];
}

export function parseTf(text) {
  return text.split(',').map((part) => {
    const [value, colour, opacity] = part.split(':');
    return { value: Number(value), colour: `#${colour}`, opacity: Number(opacity) };
  });
}

export function formatTf(points) {
  return points
    .map((p) => `${Number(p.value.toPrecision(6))}:${p.colour.slice(1)}:${Number(p.opacity.toFixed(3))}`)
    .join(',');
}

export class TfEditor {
  // `canvas` draws the editor, `colourInput` edits the selected point's
  // colour, `onChange(text)` runs after every edit.
  constructor(canvas, colourInput, onChange) {
    this.canvas = canvas;
    this.colourInput = colourInput;
    this.onChange = onChange;
    this.points = [];
    this.histogram = [];
    this.range = [0, 1];
    this.selected = -1;
    this.drag = null;
    canvas.addEventListener('pointerdown', (e) => this.down(e));
    canvas.addEventListener('pointermove', (e) => this.move(e));
    canvas.addEventListener('pointerup', (e) => this.up(e));
    canvas.addEventListener('dblclick', (e) => this.doubleClick(e));
    colourInput.addEventListener('input', () => {
      if (this.selected < 0) return;
      this.points[this.selected].colour = colourInput.value;
      this.changed();
    });
  }

  // A dataset's histogram and value range; `text` the transfer function to edit.
  load(histogram, range, text) {
    this.histogram = histogram;
    this.range = range[1] > range[0] ? range : [range[0], range[0] + 1];
    this.points = parseTf(text);
    this.selected = -1;
    this.draw();
    this.canvas.dataset.tf = this.text();
  }

  text() {
    return formatTf(this.points);
  }

  // Canvas pixels ↔ (value, opacity).
  toX(value) {
    const [lo, hi] = this.range;
    return ((value - lo) / (hi - lo)) * this.canvas.width;
  }
  toY(opacity) {
    return (1 - opacity) * (this.canvas.height - 2 * HANDLE) + HANDLE;
  }
  fromEvent(e) {
    const r = this.canvas.getBoundingClientRect();
    const x = ((e.clientX - r.left) / r.width) * this.canvas.width;
    const y = ((e.clientY - r.top) / r.height) * this.canvas.height;
    const [lo, hi] = this.range;
    const value = lo + (x / this.canvas.width) * (hi - lo);
    const opacity = Math.min(1, Math.max(0, 1 - (y - HANDLE) / (this.canvas.height - 2 * HANDLE)));
    return { x, y, value, opacity };
  }
  hit(x, y) {
    return this.points.findIndex((p) => Math.hypot(this.toX(p.value) - x, this.toY(p.opacity) - y) <= HANDLE + 3);
  }

  down(e) {
    const at = this.fromEvent(e);
    const i = this.hit(at.x, at.y);
    this.canvas.setPointerCapture(e.pointerId);
    if (i >= 0) {
      this.selected = i;
      this.colourInput.value = this.points[i].colour;
      this.drag = { kind: 'point', i };
    } else {
      this.drag = { kind: 'window', start: at, original: this.points.map((p) => ({ ...p })) };
    }
    this.draw();
  }

  move(e) {
    if (!this.drag) return;
    const at = this.fromEvent(e);
    const [rangeLo, rangeHi] = this.range;
    if (this.drag.kind === 'point') {
      // Between its neighbours, and within the histogram's range.
      const i = this.drag.i;
      const lo = Math.max(rangeLo, i > 0 ? this.points[i - 1].value : -Infinity);
      const hi = Math.min(rangeHi, i + 1 < this.points.length ? this.points[i + 1].value : Infinity);
      this.points[i].value = Math.min(hi, Math.max(lo, at.value));
      this.points[i].opacity = at.opacity;
    } else {
      this.points = this.windowed(this.drag.original, at.value - this.drag.start.value, at.y - this.drag.start.y);
    }
    this.changed();
  }

  // `original` moved by `shift` (level) and spread by `dy` pixels (window),
  // kept on the histogram: the middle of what they show within the value
  // range, and between MIN_SPREAD and MAX_SPREAD of it wide.
  windowed(original, shift, dy) {
    const [lo, hi] = this.range;
    const extent = hi - lo;
    const middle = (original[0].value + original[original.length - 1].value) / 2;
    const span = shownSpan(original) || [original[0].value, original[original.length - 1].value];
    const spread = Math.max(span[1] - span[0], Number.EPSILON);
    const scale = Math.min(
      Math.max(Math.exp(dy / 100), (MIN_SPREAD * extent) / spread),
      Math.max(1, (MAX_SPREAD * extent) / spread),
    );
    const moved = original.map((p) => ({ ...p, value: middle + (p.value - middle) * scale + shift }));
    const [a, b] = shownSpan(moved) || [moved[0].value, moved[moved.length - 1].value];
    const centre = (a + b) / 2;
    const fix = Math.min(hi, Math.max(lo, centre)) - centre;
    return moved.map((p) => ({ ...p, value: p.value + fix }));
  }

  up(e) {
    if (this.drag) this.canvas.releasePointerCapture(e.pointerId);
    this.drag = null;
  }

  doubleClick(e) {
    const at = this.fromEvent(e);
    const i = this.hit(at.x, at.y);
    if (i >= 0) {
      if (this.points.length > 2) {
        this.points.splice(i, 1);
        this.selected = -1;
      }
    } else {
      const index = this.points.findIndex((p) => p.value > at.value);
      const next = index < 0 ? this.points.length : index;
      const neighbour = this.points[Math.min(next, this.points.length - 1)];
      const value = Math.min(this.range[1], Math.max(this.range[0], at.value));
      this.points.splice(next, 0, { value, colour: neighbour.colour, opacity: at.opacity });
      this.selected = next;
    }
    this.changed();
  }

  // After every edit: redraw, keep the text on the canvas (`data-tf`, for
  // tests and inspection) and tell the page.
  changed() {
    this.draw();
    this.canvas.dataset.tf = this.text();
    this.onChange(this.text());
  }

  draw() {
    const c = this.canvas;
    const g = c.getContext('2d');
    g.clearRect(0, 0, c.width, c.height);
    // The histogram, log counts.
    const logs = this.histogram.map((n) => Math.log1p(n));
    const top = Math.max(1e-9, ...logs);
    const bin = c.width / Math.max(1, logs.length);
    g.fillStyle = 'rgba(160, 170, 190, 0.35)';
    logs.forEach((l, k) => {
      const h = (l / top) * (c.height - HANDLE);
      g.fillRect(k * bin, c.height - h, bin - 1, h);
    });
    // The colour bar along the bottom, and the opacity curve.
    const gradient = g.createLinearGradient(0, 0, c.width, 0);
    for (const p of this.points) {
      const t = this.toX(p.value) / c.width;
      if (t >= 0 && t <= 1) gradient.addColorStop(t, p.colour);
    }
    g.fillStyle = this.points.length ? gradient : '#000';
    g.fillRect(0, c.height - 4, c.width, 4);
    g.strokeStyle = '#e8e8e8';
    g.lineWidth = 1.5;
    g.beginPath();
    this.points.forEach((p, i) => {
      const [x, y] = [this.toX(p.value), this.toY(p.opacity)];
      if (i === 0) {
        g.moveTo(0, y);
        g.lineTo(x, y);
      } else g.lineTo(x, y);
      if (i === this.points.length - 1) g.lineTo(c.width, y);
    });
    g.stroke();
    this.points.forEach((p, i) => {
      g.beginPath();
      g.arc(this.toX(p.value), this.toY(p.opacity), HANDLE, 0, 2 * Math.PI);
      g.fillStyle = p.colour;
      g.fill();
      g.strokeStyle = i === this.selected ? '#ffcc00' : '#ffffff';
      g.stroke();
    });
  }
}
