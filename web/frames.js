// Frame requests over HTTP with "latest state wins": at most one request in
// flight; a change while it runs marks the view dirty and one more request,
// with the newest state, follows when it returns. Nothing stale queues up.
// Parameters: see server/src/frame_query.rs (keep in sync).

export class FrameFetcher {
  // `draw(bitmap, info)` shows a frame; `fail(message)` reports an error.
  constructor(draw, fail) {
    this.draw = draw;
    this.fail = fail;
    this.inFlight = false;
    this.pending = null;
  }

  // Asks for a frame of `params` (an object of query parameters).
  request(params) {
    this.pending = params;
    if (!this.inFlight) this.next();
  }

  async next() {
    const params = this.pending;
    this.pending = null;
    if (!params) return;
    this.inFlight = true;
    const started = performance.now();
    try {
      const response = await fetch('/api/render?' + new URLSearchParams(params));
      if (!response.ok) {
        const body = await response.json().catch(() => ({}));
        this.fail(body.error || `HTTP ${response.status}`);
      } else {
        const bitmap = await createImageBitmap(await response.blob());
        this.draw(bitmap, {
          width: bitmap.width,
          height: bitmap.height,
          renderMs: Number(response.headers.get('x-render-ms')),
          encodeMs: Number(response.headers.get('x-encode-ms')),
          reduction: Number(response.headers.get('x-reduction')),
          levels: response.headers.get('x-levels') || '',
          refinement: response.headers.get('x-refinement'),
          roundTripMs: performance.now() - started,
        });
      }
    } catch (e) {
      this.fail(`cannot reach the server: ${e.message}`);
    } finally {
      this.inFlight = false;
      if (this.pending) this.next();
    }
  }
}
