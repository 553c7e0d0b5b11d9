// Orbit camera state and the pointer, wheel and touch gestures that change it.
// Angles in degrees, distance in bounding-sphere radii: the units of the
// `az`, `el` and `dist` parameters of GET /api/render
// (keep in sync with server/src/frame_query.rs and shaders/src/camera.rs).

export const DEFAULT_CAMERA = Object.freeze({ az: 0, el: 0, dist: 3 });
const MIN_DIST = 0.05;
const MAX_DIST = 100;
const DEGREES_PER_PIXEL = 0.4;

export class OrbitCamera {
  constructor() {
    this.reset();
  }

  reset() {
    Object.assign(this, DEFAULT_CAMERA);
  }

  orbit(dxPixels, dyPixels) {
    this.az = wrapDegrees(this.az - dxPixels * DEGREES_PER_PIXEL);
    this.el = clamp(this.el + dyPixels * DEGREES_PER_PIXEL, -90, 90);
  }

  zoom(factor) {
    this.dist = clamp(this.dist * factor, MIN_DIST, MAX_DIST);
  }

  params() {
    return { az: this.az.toFixed(2), el: this.el.toFixed(2), dist: this.dist.toFixed(3) };
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
