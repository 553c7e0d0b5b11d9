// Orbit camera state and the pointer, wheel, touch and key gestures that change
// it. Angles in degrees, distance in bounding-sphere radii, the target in mm
// from the volume's centre: the view settings `az`, `el`, `dist`, `tx`, `ty`
// and `tz`, whose defaults and ranges come from the server's schema (GET
// /api/settings). A reset asks the server to `fit` the camera to what the
// transfer function shows; the server answers with the camera it chose
// (`adopt`).
//
// Gestures: drag (one finger) orbits; right or middle drag, Ctrl-drag or a
// two-finger drag pans (moves the target across the view); the wheel or a
// pinch zooms towards the cursor or the fingers (the point under them stays
// put); double-click resets. Keys on the focused view: arrows orbit,
// Shift+arrows pan, + and − zoom, R resets.

const DEGREES_PER_PIXEL = 0.4;
// How far one key press turns (degrees), pans (pixels) and zooms (factor).
const KEY_DEGREES = 5;
const KEY_PAN_PIXELS = 40;
const KEY_ZOOM = 1.15;

export class OrbitCamera {
  // `schema`: the view settings (settings.js `Schema`).
  constructor(schema) {
    this.az0 = schema.default('az');
    this.el0 = schema.default('el');
    this.dist0 = schema.default('dist');
    this.target0 = ['tx', 'ty', 'tz'].map((name) => schema.default(name));
    this.fov = schema.default('fov');
    const el = schema.get('el');
    const dist = schema.get('dist');
    const tx = schema.get('tx');
    this.elRange = [el.min, el.max];
    this.distRange = [dist.min, dist.max];
    this.targetRange = [tx.min, tx.max];
    // The volume's bounding-sphere radius (mm): `dist`'s unit.
    this.radius = 1;
    this.reset();
  }

  // The radius (mm) of the shown volume's bounding sphere (GET
  // /api/datasets `radius_mm`).
  setRadius(mm) {
    if (mm > 0) this.radius = mm;
  }

  // The image's right and up as unit vectors in patient space (LPS), as the
  // server's `Camera::basis` (no roll).
  axes() {
    const az = (this.az * Math.PI) / 180;
    const el = (this.el * Math.PI) / 180;
    const towardEye = [Math.sin(az) * Math.cos(el), -Math.cos(az) * Math.cos(el), Math.sin(el)];
    const right = [Math.cos(az), Math.sin(az), 0];
    const up = [
      towardEye[1] * right[2] - towardEye[2] * right[1],
      towardEye[2] * right[0] - towardEye[0] * right[2],
      towardEye[0] * right[1] - towardEye[1] * right[0],
    ];
    return { right, up };
  }

  // Where model point `p` (mm) shows in a view of `width` × `height` pixels
  // ([x, y] from the top left), as the server's `Camera::view_proj`
  // projects it; null behind the eye.
  project(p, width, height, orthographic) {
    const az = (this.az * Math.PI) / 180;
    const el = (this.el * Math.PI) / 180;
    const towardEye = [Math.sin(az) * Math.cos(el), -Math.cos(az) * Math.cos(el), Math.sin(el)];
    const { right, up } = this.axes();
    const eye = this.target.map((t, i) => t + towardEye[i] * this.dist * this.radius);
    const d = p.map((v, i) => v - eye[i]);
    const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    const depth = -dot(d, towardEye);
    const tan = Math.tan(((this.fov / 2) * Math.PI) / 180);
    const aspect = width / Math.max(1, height);
    const half = orthographic ? this.dist * this.radius * tan : depth * tan;
    if (!orthographic && depth <= 0) return null;
    const x = dot(d, right) / (half * aspect);
    const y = dot(d, up) / half;
    return [((x + 1) / 2) * width, ((1 - y) / 2) * height];
  }

  // Millimetres per pixel at the target, for a view `heightPixels` tall.
  mmPerPixel(heightPixels) {
    const halfHeight = this.dist * this.radius * Math.tan(((this.fov / 2) * Math.PI) / 180);
    return (2 * halfHeight) / Math.max(1, heightPixels);
  }

  // Moves the target so the picture follows a drag of (dx, dy) pixels in a
  // view `heightPixels` tall.
  pan(dx, dy, heightPixels) {
    const k = this.mmPerPixel(heightPixels);
    const { right, up } = this.axes();
    this.target = this.target.map((t, i) => clamp(t - (right[i] * dx - up[i] * dy) * k, ...this.targetRange));
    this.fit = false;
  }

  // Zooms by `factor` (below 1 nearer) keeping the point under (ox, oy)
  // pixels from the view's centre where it is, in a view `heightPixels` tall.
  zoomAt(factor, ox, oy, heightPixels) {
    const before = this.dist;
    this.zoom(factor);
    const applied = this.dist / before;
    const k = this.mmPerPixel(heightPixels) / applied;
    const { right, up } = this.axes();
    this.target = this.target.map(
      (t, i) => clamp(t + (right[i] * ox - up[i] * oy) * k * (1 - applied), ...this.targetRange),
    );
  }

  // The default angles, framing what the transfer function shows.
  reset() {
    this.az = this.az0;
    this.el = this.el0;
    this.dist = this.dist0;
    this.target = [...this.target0];
    this.fit = true;
  }

  // Takes the distance and target of the camera a fit chose (the server's
  // `camera` message, settings by name).
  adopt(set) {
    if (typeof set.dist === 'number') this.dist = set.dist;
    const target = ['tx', 'ty', 'tz'].map((name) => set[name]);
    if (target.every((v) => typeof v === 'number')) this.target = target;
    this.fit = false;
  }

  orbit(dxPixels, dyPixels) {
    this.az = wrapDegrees(this.az - dxPixels * DEGREES_PER_PIXEL);
    this.el = clamp(this.el + dyPixels * DEGREES_PER_PIXEL, ...this.elRange);
  }

  zoom(factor) {
    this.dist = clamp(this.dist * factor, ...this.distRange);
    this.fit = false;
  }

  // The view settings (numbers rounded as the server rounds a fit's).
  params() {
    const round = (v, digits) => Number(v.toFixed(digits));
    const [tx, ty, tz] = this.target.map((v) => round(v, 2));
    return {
      az: round(this.az, 2), el: round(this.el, 2), dist: round(this.dist, 3), tx, ty, tz, fit: this.fit,
    };
  }
}

// Wires gestures on `element` to `camera`. `onChange(interacting)` runs after
// every change; `interacting` is true while a gesture is under way.
export function attachGestures(element, camera, onChange) {
  const pointers = new Map();
  let pinchDistance = 0;
  let pinchMiddle = null;
  // Offset of a client point from the view's centre, and the view's height.
  const offset = (x, y) => {
    const r = element.getBoundingClientRect();
    return [x - (r.left + r.width / 2), y - (r.top + r.height / 2), r.height];
  };

  element.addEventListener('contextmenu', (e) => e.preventDefault());
  element.addEventListener('pointerdown', (e) => {
    element.setPointerCapture(e.pointerId);
    // Right or middle button, or Ctrl with the left one: pan.
    const pan = e.button === 1 || e.button === 2 || (e.button === 0 && (e.ctrlKey || e.metaKey));
    pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, pan });
    element.classList.add('dragging');
    pinchDistance = spread(pointers);
    pinchMiddle = middle(pointers);
  });

  element.addEventListener('pointermove', (e) => {
    const last = pointers.get(e.pointerId);
    if (!last) return;
    const dx = e.clientX - last.x;
    const dy = e.clientY - last.y;
    pointers.set(e.pointerId, { ...last, x: e.clientX, y: e.clientY });
    const height = element.getBoundingClientRect().height;
    if (pointers.size === 1) {
      if (last.pan) camera.pan(dx, dy, height);
      else camera.orbit(dx, dy);
    } else if (pointers.size === 2) {
      // Two fingers: the pinch zooms about their middle, which pans as it moves.
      const d = spread(pointers);
      const m = middle(pointers);
      if (pinchDistance > 0 && d > 0) {
        const [ox, oy] = offset(m.x, m.y);
        camera.zoomAt(pinchDistance / d, ox, oy, height);
      }
      if (pinchMiddle) camera.pan(m.x - pinchMiddle.x, m.y - pinchMiddle.y, height);
      pinchDistance = d;
      pinchMiddle = m;
    }
    onChange(true);
  });

  const end = (e) => {
    pointers.delete(e.pointerId);
    pinchDistance = spread(pointers);
    pinchMiddle = middle(pointers);
    if (pointers.size === 0) {
      element.classList.remove('dragging');
      onChange(false);
    }
  };
  element.addEventListener('pointerup', end);
  element.addEventListener('pointercancel', end);

  element.addEventListener('wheel', (e) => {
    e.preventDefault();
    const [ox, oy, height] = offset(e.clientX, e.clientY);
    camera.zoomAt(Math.exp(e.deltaY * 0.001), ox, oy, height);
    onChange(true);
  }, { passive: false });

  // Keys, while the view has the focus (it takes it by Tab or a click).
  element.addEventListener('keydown', (e) => {
    if (e.altKey || e.ctrlKey || e.metaKey) return;
    const height = element.getBoundingClientRect().height;
    const arrows = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, -1], ArrowDown: [0, 1] };
    if (e.key in arrows) {
      const [x, y] = arrows[e.key];
      if (e.shiftKey) camera.pan(x * KEY_PAN_PIXELS, y * KEY_PAN_PIXELS, height);
      else camera.orbit((x * KEY_DEGREES) / DEGREES_PER_PIXEL, (y * KEY_DEGREES) / DEGREES_PER_PIXEL);
    } else if (e.key === '+' || e.key === '=') {
      camera.zoom(1 / KEY_ZOOM);
    } else if (e.key === '-' || e.key === '_') {
      camera.zoom(KEY_ZOOM);
    } else if (e.key === 'r' || e.key === 'R') {
      camera.reset();
    } else {
      return;
    }
    e.preventDefault();
    onChange(false);
  });

  element.addEventListener('dblclick', () => {
    camera.reset();
    onChange(false);
  });
}

function middle(pointers) {
  if (pointers.size !== 2) return null;
  const [a, b] = [...pointers.values()];
  return { x: (a.x + b.x) / 2, y: (a.y + b.y) / 2 };
}

// The distance between two pointers (0 unless there are two).
export function spread(pointers) {
  if (pointers.size !== 2) return 0;
  const [a, b] = [...pointers.values()];
  return Math.hypot(a.x - b.x, a.y - b.y);
}

function clamp(v, lo, hi) {
  return Math.min(hi, Math.max(lo, v));
}

function wrapDegrees(v) {
  return ((v % 360) + 540) % 360 - 180;
}
