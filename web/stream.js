// A view session over WebSocket (GET /api/stream). The protocol is documented
// in server/src/protocol.rs (keep in sync): JSON `view` messages carry only
// the settings that changed, each with a rising id, for one of the views
// (`pane`: the 3D view `3d`, or the slice views `axial`, `coronal`,
// `sagittal`, each with settings of its own); a `layout` message says which
// views are shown (only they are rendered); binary frames come back with a
// 48-byte little-endian header naming their view, a slice frame after a
// `slice` message saying where it lies; `probe` (the voxel at a point) and
// `pick` (the first visible point under a pixel of the 3D view) are
// answered by messages of their type with the same id (`ask`); every drawn frame is acknowledged, and
// the server sends nothing more until it is, so a slow link drops frames
// instead of building lag. The server decides the quality: small JPEG frames
// while views keep coming, then the lossless full frame, then light
// refinements until converged. A view with `fit: true` is answered by a
// `camera` message (the camera the server chose, now the session's) before
// its frame. A `status` message ({type:'status', id}) is
// answered in order by {type:'status', id, view_id, sent, acked, rendering,
// waiting, converged} (tests use it); this client sends none and ignores
// the replies. A server shutting down closes the socket with code 1001; the
// client reconnects as after any close, except after code 4408 (the session
// was idle and closed to free its place): then it reconnects when the view
// changes next; and after code 4401 (the access token expired): then it logs
// in again (auth.js). The token rides as the subprotocol `bearer.TOKEN`.
// The whole view goes once the session's hello has arrived (its dataset list
// may have changed since the page loaded: `hello(message)` adopts it first).
// A refused view message (an `error` with its id) changed nothing on the
// server: the names it set are no longer taken as sent, and the next view
// carries them again (not at once: the refused value may still be there).
// A socket that closes before it opened was refused (a full server answers
// the upgrade with 503, too many sessions from this client with 429) or
// never reached the server; the WebSocket API hides which, so the client
// asks with a plain GET /api/stream (426 where a session could open now)
// and tells the user the server's reason, then tries again after the
// server's Retry-After, doubled on each refusal in a row up to a minute.

import { authFetch, logInAgain, socketProtocols } from './auth.js';

export const HEADER_LEN = 48;
// The views by their number in frame headers.
export const PANES = ['3d', 'axial', 'coronal', 'sagittal'];
// The close code of a session closed for being idle (protocol.rs CLOSE_IDLE).
const CLOSE_IDLE = 4408;
// The close code of a session whose access token expired (CLOSE_EXPIRED).
const CLOSE_EXPIRED = 4401;
const ENCODINGS = { 1: 'image/jpeg', 2: 'image/png', 3: 'image/webp' };
// The longest wait between tries to open a session, in seconds.
const MAX_RETRY_S = 60;

// The header of a binary frame (see server/src/protocol.rs `FrameHeader`).
export function parseHeader(buffer) {
  const v = new DataView(buffer);
  const magic = String.fromCharCode(v.getUint8(0), v.getUint8(1), v.getUint8(2), v.getUint8(3));
  if (magic !== 'VXF1') throw new Error(`frame magic '${magic}': expected 'VXF1'`);
  return {
    encoding: v.getUint8(4),
    lossless: (v.getUint8(5) & 1) !== 0,
    converged: (v.getUint8(5) & 2) !== 0,
    memoryLimited: (v.getUint8(5) & 4) !== 0,
    width: v.getUint16(6, true),
    height: v.getUint16(8, true),
    refined: v.getUint16(10, true),
    directions: v.getUint16(12, true),
    pendingBlocks: v.getUint16(14, true),
    frameId: v.getUint32(16, true),
    messageId: v.getUint32(20, true),
    renderMs: v.getFloat32(24, true),
    encodeMs: v.getFloat32(28, true),
    reduction: v.getFloat32(32, true),
    queueMs: v.getFloat32(36, true),
    emptyShare: v.getFloat32(40, true),
    pane: PANES[v.getUint8(44)],
  };
}

export class ViewStream {
  // `draw(bitmap, info, blob)` shows a frame (the blob: its encoded image), `fail(message)` reports an error,
  // `hello(message)` receives the server's greeting (dataset, settings),
  // `camera(set)` takes the camera a fit chose and returns the view settings
  // the client now holds for it (the server has them: they are not sent back);
  // `attempted(n)` hears of each try to open a session (n so far).
  constructor(draw, fail, hello, camera, attempted = () => {}) {
    this.draw = draw;
    this.fail = fail;
    this.hello = hello;
    this.camera = camera;
    this.attempted = attempted;
    this.attempts = 0;
    // Tries in a row that did not open a session.
    this.refusals = 0;
    // Per view: the settings it should have, and those the server has.
    this.views = {};
    this.sent = {};
    this.dpr = 1;
    this.sentDpr = null;
    this.layout = ['3d'];
    this.sentLayout = null;
    this.id = 0;
    // The last view message id sent per view, and the placements of slice
    // frames by frame id (from the `slice` message before each).
    this.lastIds = {};
    this.placements = new Map();
    // Probes and picks awaiting their answer, by id.
    this.asked = new Map();
    this.sentAt = new Map();
    // The names each view message not yet reflected by a frame set, by id:
    // a refused message changed nothing on the server, so they are sent
    // again with the next view.
    this.messages = new Map();
    this.greeted = false;
    this.connect();
  }

  connect() {
    const scheme = location.protocol === 'https:' ? 'wss://' : 'ws://';
    const socket = new WebSocket(`${scheme}${location.host}/api/stream`, socketProtocols());
    socket.binaryType = 'arraybuffer';
    this.attempts += 1;
    this.attempted(this.attempts);
    socket.onopen = () => {
      socket.opened = true;
      this.refusals = 0;
      // A new session knows nothing: the whole view goes once the hello has
      // said what the server offers now (after a restart its datasets may
      // differ, and a view naming one that is gone would be refused whole).
      this.sent = {};
      this.sentDpr = null;
      this.sentLayout = null;
      this.greeted = false;
      this.messages.clear();
    };
    socket.onmessage = (event) => this.receive(event.data);
    socket.onclose = (event) => {
      if (event.code === CLOSE_EXPIRED) {
        this.fail('the login has expired: logging in again…');
        logInAgain();
        return;
      }
      if (event.code === CLOSE_IDLE) {
        socket.idleClosed = true;
        this.fail('paused while idle: move the view to resume');
        return;
      }
      if (!socket.opened) {
        this.retryRefused();
        return;
      }
      // 1001: the server (a node behind a load balancer) is draining; the
      // next session may open on another node at once.
      const away = event.code === 1001;
      this.fail(away ? 'the server is restarting: reconnecting…'
        : 'connection to the server lost: reconnecting…');
      setTimeout(() => this.connect(), away ? 250 : 1000);
    };
    this.socket = socket;
  }

  // After a socket closed without opening: why (see the top of this file),
  // shown, and another try after a wait that doubles while refusals go on.
  async retryRefused() {
    let reason;
    let wait = 1;
    try {
      const response = await authFetch('/api/stream');
      if (response.status === 426) {
        // Room now (a place freed in between): try again at once.
        reason = null;
      } else {
        const body = await response.json().catch(() => ({}));
        reason = body.error || `the server answered ${response.status}`;
        wait = Number(response.headers.get('Retry-After')) || 2;
      }
    } catch (e) {
      reason = `cannot reach the server (${e.message})`;
    }
    this.refusals += 1;
    const first = reason === null ? 0.25 : wait;
    const delay = Math.min(MAX_RETRY_S, first * 2 ** (this.refusals - 1));
    if (reason === null && this.refusals > 2) reason = 'the view session did not open';
    if (reason !== null) this.fail(`${reason}; trying again in ${Math.round(delay)} s`);
    setTimeout(() => this.connect(), delay * 1000);
  }

  // Sets the whole view of `pane` (settings as GET /api/settings lists
  // them for it; w and h in CSS pixels). Whether a view message went
  // (false: nothing changed, or it goes once the session is open).
  update(view, dpr, pane = '3d') {
    this.views[pane] = { ...view };
    this.dpr = dpr;
    if (this.socket.readyState === WebSocket.CLOSED && this.socket.idleClosed) {
      this.connect();
      return false;
    }
    return this.flush().includes(pane);
  }

  // Sends every view whole with the next update (the dataset behind the
  // same id was replaced: each view is drawn again).
  resendAll() {
    this.sent = {};
    this.sentDpr = null;
  }

  // Shows these views (the others are not rendered).
  setLayout(panes) {
    this.layout = [...panes];
    this.flush();
  }

  // Sends what changed; the views a message went for.
  flush() {
    if (!this.greeted || this.socket.readyState !== WebSocket.OPEN) return [];
    if (String(this.sentLayout) !== String(this.layout)) {
      this.socket.send(JSON.stringify({ type: 'layout', panes: this.layout }));
      this.sentLayout = [...this.layout];
    }
    const went = [];
    for (const [pane, view] of Object.entries(this.views)) {
      const sent = this.sent[pane] || {};
      const set = {};
      for (const [name, value] of Object.entries(view)) {
        if (sent[name] !== value) set[name] = value;
      }
      // A setting no longer in the view goes back to its default.
      for (const name of Object.keys(sent)) {
        if (!(name in view)) set[name] = null;
      }
      if (Object.keys(set).length === 0 && this.sentDpr === this.dpr) continue;
      this.id += 1;
      this.sentAt.set(this.id, { pane, at: performance.now() });
      this.lastIds[pane] = this.id;
      this.messages.set(this.id, { pane, names: Object.keys(set), dpr: this.sentDpr !== this.dpr });
      this.socket.send(JSON.stringify({ type: 'view', id: this.id, pane, set, dpr: this.dpr }));
      this.sent[pane] = { ...view };
      this.sentDpr = this.dpr;
      went.push(pane);
    }
    return went;
  }

  // Asks a `probe` or `pick` (`fields` besides type and id); resolves with
  // the answer, or null when the session cannot ask now or the server
  // refused (its error is shown).
  ask(type, fields) {
    if (!this.greeted || this.socket.readyState !== WebSocket.OPEN) return Promise.resolve(null);
    this.id += 1;
    const id = this.id;
    this.socket.send(JSON.stringify({ type, id, ...fields }));
    return new Promise((resolve) => this.asked.set(id, resolve));
  }

  // The server refused view message `id` and kept its settings as they were:
  // what it set is no longer taken as sent (not sent again at once: the
  // refused value may still be in the view; the next view carries them).
  forget(id) {
    const asked = this.asked.get(id);
    if (asked) {
      this.asked.delete(id);
      asked(null);
    }
    const message = this.messages.get(id);
    if (!message) return;
    this.messages.delete(id);
    const sent = this.sent[message.pane] || {};
    for (const name of message.names) delete sent[name];
    if (message.dpr) this.sentDpr = null;
  }

  async receive(data) {
    if (typeof data === 'string') {
      const message = JSON.parse(data);
      if (message.type === 'error') {
        this.forget(message.id);
        this.fail(message.message);
      } else if (message.type === 'hello') {
        this.hello(message);
        this.greeted = true;
        this.flush();
      }
      else if (message.type === 'camera') {
        const held = this.camera(message.set);
        this.sent['3d'] = { ...(this.sent['3d'] || {}), ...held };
        if (this.views['3d']) Object.assign(this.views['3d'], held);
      } else if (message.type === 'slice') {
        this.placements.set(message.frame, message);
      } else if (message.type === 'probe' || message.type === 'pick') {
        const asked = this.asked.get(message.id);
        this.asked.delete(message.id);
        if (asked) asked(message);
      }
      return;
    }
    let header;
    try {
      header = parseHeader(data);
    } catch (e) {
      this.fail(e.message);
      return;
    }
    const type = ENCODINGS[header.encoding] || 'application/octet-stream';
    const blob = new Blob([new Uint8Array(data, HEADER_LEN)], { type });
    const bitmap = await createImageBitmap(blob);
    const sentAt = this.sentAt.get(header.messageId)?.at;
    for (const [id, sent] of this.sentAt) {
      if (id < header.messageId && sent.pane === header.pane) this.sentAt.delete(id);
    }
    // Ids rise across views: those below the frame's are done only for its own.
    for (const [id, message] of this.messages) {
      if (id <= header.messageId && message.pane === header.pane) this.messages.delete(id);
    }
    const placement = this.placements.get(header.frameId) || null;
    this.placements.delete(header.frameId);
    this.draw(bitmap, {
      ...header,
      placement,
      latencyMs: sentAt === undefined ? NaN : performance.now() - sentAt,
      // Whether it shows the last view sent for its view (later ones may be on their way).
      latest: header.messageId >= (this.lastIds[header.pane] || 0),
    }, blob);
    if (this.socket.readyState === WebSocket.OPEN) {
      this.socket.send(JSON.stringify({ type: 'ack', frame: header.frameId }));
    }
  }
}
