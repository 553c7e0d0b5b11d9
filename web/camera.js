// Orbit camera state and the pointer, wheel and touch gestures that change it.
// Angles in degrees, distance in bounding-sphere radii, the target in mm from
// the volume's centre: the view settings `az`, `el`, `dist`, `tx`, `ty` and
// `tz`, whose defaults and ranges come from the server's schema (GET
// /api/settings). A reset asks the server to `fit` the camera to what the
// transfer function shows; the server answers with the camera it chose
// (`adopt`).

const DEGREES_PER_PIXEL = 0.4;

export class OrbitCamera {
  // `schema`: the view settings (settings.js `Schema`).
  constructor(schema) {
    this.az0 = schema.default('az');
    this.el0 = schema.default('el');
    this.dist0 = schema.default('dist');
    this.target0 = ['tx', 'ty', 'tz'].map((name) => schema.default(name));
    const el = schema.get('el');
    const dist = schema.get('dist');
    this.elRange = [el.min, el.max];
    this.distRange = [dist.min, dist.max];
    this.reset();
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

  element.addEventListener('pointerdown', (e) => {
    element.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
    element.classList.add('dragging');
    pinchDistance = spread(pointers);
  });

  element.addEventListener('pointermove', (e) => {
    const last = pointers.get(e.pointerId);
    if (!last) return;
    const dx = e.clientX - last.x;
    const dy = e.clientY - last.y;
    pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
    if (pointers.size === 1) {
      camera.orbit(dx, dy);
    } else if (pointers.size === 2) {
      const d = spread(pointers);
      if (pinchDistance > 0 && d > 0) camera.zoom(pinchDistance / d);
      pinchDistance = d;
    }
    onChange(true);
  });

  const end = (e) => {
    pointers.delete(e.pointerId);
    pinchDistance = spread(pointers);
    if (pointers.size === 0) {
      element.classList.remove('dragging');
      onChange(false);
    }
  };
  element.addEventListener('pointerup', end);
  element.addEventListener('pointercancel', end);

  element.addEventListener('wheel', (e) => {
    e.preventDefault();
    camera.zoom(Math.exp(e.deltaY * 0.001));
    onChange(true);
  }, { passive: false });

  element.addEventListener('dblclick', () => {
    camera.reset();
    onChange(false);
  });
}

function spread(pointers) {
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
