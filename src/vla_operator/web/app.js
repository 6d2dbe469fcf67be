// The operator station's page: live view with boxes to choose from, driving by buttons, keys, switches
// or a gamepad, the e-stop, status in words, episodes and the caregiver's settings.
import { Link } from './link.js';

const $ = (id) => document.getElementById(id);
const state = { driver: false, boxes: [], size: [640, 480], latched: null, speed: 0.6, settings: {},
                held: 0, toggled: 0, sent: {}, replies: {}, scan: -1, frames: 0, fpsT: performance.now(), fps: 0, age: null };
window.station = state;  // read by the browser tests and the benchmark

function say(text) { $('message').textContent = text; }

const link = new Link(onMessage, onFrame, (up) => {
  $('connection').textContent = up ? 'Connected to the robot' : 'Not connected: the arm is stopped';
});

function onMessage(m) {
  if (m.type === 'hello' || m.type === 'role') setRole(m.driver);
  else if (m.type === 'state') showState(m);
  else if (m.type === 'reply') {
    state.replies[m.what] = performance.now() - (state.sent[m.what] ?? NaN);
    if (m.what === 'estop' && m.ok) state.estopLatency = performance.now() - state.estopSent;
    say(`${m.what}: ${m.ok ? 'done' : 'refused'}${m.message ? ' – ' + m.message : ''}`);
  }
  else if (m.type === 'refused') say(`Refused: ${m.reason}`);
}

function setRole(driver) {
  state.driver = driver;
  $('s-role').textContent = driver ? 'Driving' : 'Watching (another station drives; you may press STOP)';
}

function showState(s) {
  const c = s.controller, f = s.safety;
  if (c) {
    $('s-controller').textContent = c.words + (c.reason ? ` (${c.reason})` : '');
    $('s-mode').textContent = c.mode;
    state.latched = c.latched_class ? c : null;
    $('target').textContent = c.latched_class ? `Latched: ${c.latched_class} (chosen by ${c.latched_by})`
                                              : 'No object latched';
  }
  if (f) {
    $('s-safety').textContent = f.words + (f.text ? ` (${f.text})` : '');
    $('s-teaching').textContent = f.teaching ? 'On' : 'Off';
    $('teaching').setAttribute('aria-pressed', String(f.teaching));
  }
  if (s.gripper) $('s-gripper').textContent = s.gripper.text || (s.gripper.holding ? `holding ${s.gripper.holding}` : '–');
  if (s.recorder) $('s-recorder').textContent = s.recorder.recording ? `Recording ${s.recorder.task}` : 'Not recording';
  if (s.tasks && $('task').options.length === 0) {
    for (const t of s.tasks) $('task').add(new Option(t, t));
  }
  if (s.settings) { state.settings = s.settings; $('set-speed').value = s.settings.speed_scale ?? 1;
    $('set-mode').value = s.settings.action_mode ?? 'hold'; $('set-device').value = s.settings.input_device ?? 'buttons'; }
}

// ------------------------------------------------------------------ live view
const canvas = $('frame'), ctx = canvas.getContext('2d');
async function onFrame(blob, meta) {
  const bmp = await createImageBitmap(blob);
  if (canvas.width !== bmp.width) { canvas.width = bmp.width; canvas.height = bmp.height; }
  ctx.drawImage(bmp, 0, 0);
  bmp.close();
  state.frames++; state.age = meta.age_ms;
  const now = performance.now();
  if (now - state.fpsT >= 1000) { state.fps = state.frames * 1000 / (now - state.fpsT); state.frames = 0; state.fpsT = now;
    $('fps').textContent = state.fps.toFixed(1); $('age').textContent = state.age.toFixed(0); }
  state.size = meta.size && meta.size[0] ? meta.size : [meta.width, meta.height];
  drawBoxes(meta.boxes || []);
}

function drawBoxes(boxes) {
  state.boxes = boxes;
  const holder = $('boxes');
  while (holder.children.length > boxes.length) holder.lastChild.remove();
  boxes.forEach((b, i) => {
    let el = holder.children[i];
    if (!el) { el = document.createElement('button'); el.type = 'button'; el.append(document.createElement('span'));
      el.addEventListener('click', () => select(i)); holder.append(el); }
    const [w, h] = state.size, L = state.latched;
    Object.assign(el.style, { left: `${100 * (b.cx - b.w / 2) / w}%`, top: `${100 * (b.cy - b.h / 2) / h}%`,
                              width: `${100 * b.w / w}%`, height: `${100 * b.h / h}%` });
    const latched = L && L.latched_class === b.class_id;
    el.classList.toggle('latched', !!latched);
    const label = `${b.class_id}${latched ? ' (latched)' : ''}`;
    if (el.firstChild.textContent !== label) { el.firstChild.textContent = label;
      el.setAttribute('aria-label', `Latch ${b.class_id}, score ${b.score}${latched ? ', latched now' : ''}`); }
    el.dataset.cx = b.cx; el.dataset.cy = b.cy;
  });
}

function select(i) {
  const b = state.boxes[i];
  if (b) link.send({ type: 'select', by: 'pixel', x: b.cx, y: b.cy });
}
function step(dir) {
  const n = state.boxes.length; if (!n) return;
  const cur = state.boxes.findIndex((b) => state.latched && b.class_id === state.latched.latched_class);
  select(((cur < 0 ? (dir > 0 ? -1 : 0) : cur) + dir + n) % n);
}
$('prev').onclick = () => step(-1);
$('next').onclick = () => step(1);
$('redetect').onclick = () => link.send({ type: 'redetect' });

// ------------------------------------------------------------------ driving
document.querySelectorAll('input[name=speed]').forEach((r) => r.addEventListener('change', () => { state.speed = +r.value; }));
function mode() { return state.settings.action_mode || 'hold'; }
function press(dir) {             // dir: +1, -1
  const m = mode();
  if (m === 'toggle') { state.toggled = state.toggled === dir ? 0 : dir; drive(state.toggled); }
  else if (m === 'step') { drive(dir); setTimeout(() => release(dir, true), 300); }
  else { state.held = dir; drive(dir); }
}
function release(dir, stepEnd = false) {
  if (mode() === 'toggle') return;
  if (mode() === 'step' && !stepEnd) return;
  state.held = 0; drive(0);
}
function drive(dir) {
  link.setAxis(dir * state.speed);
  $('forward').setAttribute('aria-pressed', String(dir > 0));
  $('back').setAttribute('aria-pressed', String(dir < 0));
}
for (const [id, dir] of [['forward', 1], ['back', -1]]) {
  const el = $(id);
  el.setAttribute('aria-pressed', 'false');
  el.addEventListener('pointerdown', (e) => { el.setPointerCapture(e.pointerId); press(dir); });
  for (const ev of ['pointerup', 'pointercancel', 'lostpointercapture']) el.addEventListener(ev, () => release(dir));
  el.addEventListener('keydown', (e) => { if ((e.key === ' ' || e.key === 'Enter') && !e.repeat) { e.preventDefault(); press(dir); } });
  el.addEventListener('keyup', (e) => { if (e.key === ' ' || e.key === 'Enter') release(dir); });
}
$('gripper').onclick = () => link.send({ type: 'gripper' });

// keys: arrows drive anywhere on the page (not in a form field), Esc stops, J/K are a dual switch,
// Space is a single switch when scanning is chosen
const KEYS = { ArrowUp: 1, ArrowRight: 1, ArrowDown: -1, ArrowLeft: -1, j: 1, k: -1 };
const SCAN = ['forward', 'back', 'next', 'gripper'];
function scanning() { return (state.settings.input_device || 'buttons') === 'switch1'; }
addEventListener('keydown', (e) => {
  if (e.key === 'Escape') { e.preventDefault(); estop(); return; }
  if (e.target.matches('select, input') || e.repeat) return;
  if (scanning() && e.key === ' ') { e.preventDefault(); const id = SCAN[state.scan];
    if (id === 'forward' || id === 'back') press(id === 'forward' ? 1 : -1); else if (id) $(id).click(); return; }
  if (e.key in KEYS) { e.preventDefault(); press(KEYS[e.key]); }
});
addEventListener('keyup', (e) => {
  if (scanning() && e.key === ' ') { const id = SCAN[state.scan]; if (id === 'forward' || id === 'back') release(0); return; }
  if (e.key in KEYS) release(KEYS[e.key]);
});
setInterval(() => {        // single-switch scanning: the highlight steps every 1.5 s while nothing is held
  if (!scanning()) { if (state.scan >= 0) { document.querySelectorAll('.scan').forEach((e) => e.classList.remove('scan')); state.scan = -1; } return; }
  if (state.held) return;
  document.querySelectorAll('.scan').forEach((e) => e.classList.remove('scan'));
  state.scan = (state.scan + 1) % SCAN.length; $(SCAN[state.scan]).classList.add('scan');
}, 1500);
function pollGamepad() {   // the Gamepad API: the first pad's left stick (up = toward the task)
  const pad = (navigator.getGamepads ? navigator.getGamepads() : [])[0];
  if (pad && (state.settings.input_device === 'gamepad')) {
    const v = -pad.axes[1]; const a = Math.abs(v) < 0.15 ? 0 : Math.max(-1, Math.min(1, v));
    link.setAxis(+(a * state.speed).toFixed(2));
  }
  requestAnimationFrame(pollGamepad);
}
requestAnimationFrame(pollGamepad);

// ------------------------------------------------------------------ stop
function estop() { state.estopSent = performance.now(); state.estopLatency = null; state.held = 0; state.toggled = 0; drive(0); link.send({ type: 'estop' }); say('STOP sent'); }
$('estop').onclick = estop;
$('release').onclick = () => $('release-dialog').showModal();
$('release-cancel').onclick = () => $('release-dialog').close();
$('release-confirm').onclick = () => { link.send({ type: 'release_estop', confirm: true }); $('release-dialog').close(); };

// ------------------------------------------------------------------ episodes, teaching, settings
$('ep-start').onclick = () => link.send({ type: 'episode', action: 'start', task: $('task').value });
$('ep-stop').onclick = () => link.send({ type: 'episode', action: 'stop' });
$('ep-discard').onclick = () => link.send({ type: 'episode', action: 'discard' });
window.stationRequest = (msg, what) => { state.sent[what] = performance.now(); link.send(msg); };  // tests
$('teaching').onclick = () => link.send({ type: 'teaching', on: $('teaching').getAttribute('aria-pressed') !== 'true' });
$('view-toggle').onclick = () => {
  const show = $('settings').hidden; $('settings').hidden = !show; $('operate').hidden = show;
  $('view-toggle').setAttribute('aria-expanded', String(show));
  $('view-toggle').textContent = show ? 'Back to driving' : 'Caregiver settings';
};
$('set-save').onclick = () => link.send({ type: 'settings', values: {
  speed_scale: +$('set-speed').value, action_mode: $('set-mode').value, input_device: $('set-device').value } });
