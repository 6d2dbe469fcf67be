// The page's end of the link: one WebSocket, input as {seq, t, axis} (the station stamps and checks it),
// a heartbeat, zero when the page is hidden or closed. Nothing is queued: while the input is held it is
// re-sent at a fixed rate, and the station keeps only the latest.
const RESEND_MS = 40;
const HEARTBEAT_MS = 200;

export class Link {
  constructor(onMessage, onFrame, onConnection) {
    this.onMessage = onMessage; this.onFrame = onFrame; this.onConnection = onConnection;
    this.seq = 0; this.axis = 0; this.ws = null; this.meta = null;
    const query = new URLSearchParams(location.search), token = query.get('token') || '';
    const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const ws = new URLSearchParams();
    if (token) ws.set('token', token);
    this.watchOnly = query.get('watch') === '1';
    if (this.watchOnly) ws.set('watch', '1');   // a page that only shows (never drives, sends no input)
    this.url = `${proto}//${location.host}/ws` + (ws.toString() ? `?${ws}` : '');
    setInterval(() => this.send({ type: 'heartbeat' }), HEARTBEAT_MS);
    setInterval(() => { if (this.axis !== 0) this.sendAxis(); }, RESEND_MS);
    document.addEventListener('visibilitychange', () => { if (document.hidden) this.hidden(); });
    addEventListener('pagehide', () => { this.hidden(); if (this.ws) this.ws.close(); });
    this.connect();
  }
  connect() {
    const ws = new WebSocket(this.url);
    ws.binaryType = 'blob';
    this.ws = ws;
    ws.onopen = () => { this.onConnection(true); this.axis = 0; this.sendAxis(); };
    ws.onclose = () => { this.onConnection(false); this.axis = 0; setTimeout(() => this.connect(), 1000); };
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') {
        const m = JSON.parse(ev.data);
        if (m.type === 'frame') this.meta = m; else this.onMessage(m);
      } else if (this.meta) { this.onFrame(ev.data, this.meta); this.meta = null; }
    };
  }
  send(msg) { if (this.ws && this.ws.readyState === WebSocket.OPEN) this.ws.send(JSON.stringify(msg)); }
  setAxis(a) { const changed = a !== this.axis; this.axis = a; if (changed) this.sendAxis(); }
  sendAxis() { if (this.watchOnly) return; this.send({ type: 'input', seq: ++this.seq, t: performance.now(), axis: this.axis }); }
  hidden() { this.axis = 0; this.send({ type: 'hidden' }); }
}
