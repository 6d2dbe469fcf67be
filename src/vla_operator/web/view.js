// The live view: the newest camera frame with the detector's boxes drawn on it, the detected objects as
// buttons beside it (a row of 44 px targets that never overlap, whatever the boxes do on a small screen;
// a tap on a box in the picture chooses it too), and a stale view said in words.
import { assistText, drawGoal } from './assist.js';
import { $, setText, show } from './dom.js';
import { chosenBy, objectName } from './state.js';

const canvas = $('frame'), ctx = canvas.getContext('2d');
const BOX = '#ffd400', LATCHED = '#00e5ff';

export class LiveView {
  // onSelect(box): the person chose a detected object
  constructor(state, onSelect) {
    this.state = state; this.onSelect = onSelect;
    this.decoding = false; this.waiting = null; this.bmp = null;
    canvas.addEventListener('click', (e) => this.tap(e));
  }

  // Latest only here too: a frame that comes while one is decoded replaces the one waiting, so a busy
  // page shows the newest frame and never decodes a backlog.
  frame(blob, meta) {
    if (this.waiting) this.state.skipped = (this.state.skipped || 0) + 1;
    this.waiting = [blob, meta];
    if (!this.decoding) this.drain();
  }

  async drain() {
    this.decoding = true;
    while (this.waiting) {
      const [blob, meta] = this.waiting; this.waiting = null;
      try { this.draw(await createImageBitmap(blob), meta); } catch (e) { /* a damaged frame: the next one */ }
    }
    this.decoding = false;
  }

  draw(bmp, meta) {
    const s = this.state;
    if (canvas.width !== bmp.width || canvas.height !== bmp.height) { canvas.width = bmp.width; canvas.height = bmp.height; }
    ctx.drawImage(bmp, 0, 0);
    bmp.close();
    s.frames++; s.age = meta.age_ms; s.lastFrame = performance.now();
    const now = performance.now();
    if (now - s.fpsT >= 1000) {
      s.fps = s.frames * 1000 / (now - s.fpsT); s.frames = 0; s.fpsT = now;
      setText($('fps'), s.fps.toFixed(1)); setText($('age'), s.age.toFixed(0));
    }
    s.size = meta.size && meta.size[0] ? meta.size : [meta.width, meta.height];
    s.boxes = meta.boxes || [];
    this.drawBoxes();
    this.objects();
  }

  drawBoxes() {   // the boxes, the goal's marker, then the names (the chosen one's last: on top of any other)
    const [w, h] = this.state.size, kx = canvas.width / w, ky = canvas.height / h;
    const size = Math.round(canvas.width / 32), pad = 3;
    const boxes = [...this.state.boxes].sort((a, b) => this.isLatched(a) - this.isLatched(b));
    ctx.lineWidth = Math.max(2, canvas.width / 160);
    ctx.font = `bold ${size}px system-ui, sans-serif`;
    ctx.textBaseline = 'top';
    const rect = (b) => [(b.cx - b.w / 2) * kx, (b.cy - b.h / 2) * ky, b.w * kx, b.h * ky];
    for (const b of boxes) { ctx.strokeStyle = this.isLatched(b) ? LATCHED : BOX; ctx.strokeRect(...rect(b)); }
    drawGoal(ctx, this.state.ctrl);   // the assistance's goal over the boxes, under their names
    ctx.font = `bold ${size}px system-ui, sans-serif`;
    ctx.textBaseline = 'top';
    for (const b of boxes) {
      const [x, y] = rect(b), label = objectName(b.class_id), tw = ctx.measureText(label).width + 2 * pad;
      const top = Math.max(0, y - size - 2 * pad);
      ctx.fillStyle = this.isLatched(b) ? LATCHED : BOX;
      ctx.fillRect(x, top, tw, size + 2 * pad);
      ctx.fillStyle = '#000';
      ctx.fillText(label, x + pad, top + pad);
    }
  }

  isLatched(b) { const L = this.state.latched; return !!L && L.latched_class === b.class_id; }

  // one button per detected object, in the detector's order; the chosen one is pressed
  objects() {
    const holder = $('objects'), boxes = this.state.boxes;
    while (holder.children.length > boxes.length) holder.lastChild.remove();
    boxes.forEach((b, i) => {
      let el = holder.children[i];
      if (!el) {
        el = document.createElement('button'); el.type = 'button';
        el.addEventListener('click', () => this.onSelect(this.state.boxes[i]));
        holder.append(el);
      }
      setText(el, objectName(b.class_id));
      const pressed = String(this.isLatched(b));
      if (el.getAttribute('aria-pressed') !== pressed) el.setAttribute('aria-pressed', pressed);
    });
  }

  // a tap on the picture chooses the smallest box under it (as the controller's pick by pixel)
  tap(e) {
    const r = canvas.getBoundingClientRect(), [w, h] = this.state.size;
    const x = (e.clientX - r.left) * w / r.width, y = (e.clientY - r.top) * h / r.height;
    const hits = this.state.boxes.filter((b) => Math.abs(b.cx - x) <= b.w / 2 && Math.abs(b.cy - y) <= b.h / 2);
    if (hits.length) this.onSelect(hits.reduce((a, b) => (a.w * a.h <= b.w * b.h ? a : b)));
  }

  // the controller's assistance: its level, goal and confidence in words over the view ('' and hidden: off)
  assist(c) {
    const text = assistText(c);
    setText($('assist'), text);
    show($('assist'), !!text);
  }

  target(c) {
    const text = c && c.latched_class ? `Goal: the ${objectName(c.latched_class)} (${chosenBy(c.latched_by)})`
                                      : 'No object chosen';
    setText($('target'), text);
  }

  // the station says whether the camera went quiet (view_stale, view_age_s: null before the first
  // frame); absent fields: not stale. Returns the words for the state bar ('' when live).
  stale(s) {
    const stale = s.view_stale === true, known = Number.isFinite(s.view_age_s);
    const words = !stale ? '' : known ? 'The live view has stopped: no new picture.' : 'No picture from the camera yet.';
    setText($('view-stale'), stale && known ? `The live view has stopped: no new picture for ${Math.round(s.view_age_s)} s.` : words);
    show($('view-stale'), stale);
    $('stage').classList.toggle('is-stale', stale);
    return words;
  }
}
