// The operator station's page: live view with boxes to choose from, driving by buttons, keys, switches
// or a gamepad, the e-stop, status in words, episodes, the caregiver's settings and the study's
// questionnaire.
import { Link } from './link.js';

const $ = (id) => document.getElementById(id);
const STEP_S = 0.3;      // step mode: one press drives this long, then stops by itself (setting step_seconds)
const SCAN_S = 1.5;      // single switch: the highlight's time on each control (setting scan_period)
const PAD_GRASP = 0, PAD_STOP = 1;   // the standard gamepad's A (south) and B (east) buttons
const state = { driver: false, boxes: [], size: [640, 480], latched: null, speed: 0.6, settings: {}, settingsJson: '',
                held: 0, toggled: 0, stepTimer: 0, padAxis: 0, sent: {}, replies: {}, scan: -1, frames: 0,
                fpsT: performance.now(), fps: 0, age: null, refused: null, scanIds: [], claimed: false };
window.station = state;  // read by the browser tests and the benchmark

function say(text) { $('message').textContent = text; }

const link = new Link(onMessage, onFrame, (up) => {
  $('connection').textContent = up ? 'Connected to the robot' : 'Not connected: the arm is stopped';
});

function onMessage(m) {
  if (m.type === 'hello' || m.type === 'role') setRole(m);
  else if (m.type === 'state') showState(m);
  else if (m.type === 'reply' && m.what === 'questionnaire') questReply(m);
  else if (m.type === 'reply' && m.what === 'settings') {
    $('set-message').textContent = m.ok ? `Settings ${m.message}` : `Not saved: ${m.message}`;
  }
  else if (m.type === 'reply') {
    state.replies[m.what] = performance.now() - (state.sent[m.what] ?? NaN);
    if (m.what === 'estop' && m.ok) state.estopLatency = performance.now() - state.estopSent;
    say(`${m.what}: ${m.ok ? 'done' : 'refused'}${m.message ? ' – ' + m.message : ''}`);
  }
  else if (m.type === 'refused') {
    state.refused = m.reason; say(`Refused: ${m.reason}`);
    if (m.what === 'answers') questReply({ ok: false, message: m.reason });
  }
}

// One station drives; a watcher may take control (a confirmed dialog; the station refuses while the
// driver moves the arm). A change of role lets go of whatever this page held, without sending it: the
// new driver starts from a neutral input, so a key held through the change moves nothing.
function setRole(m) {
  const was = state.driver, driver = !!m.driver;
  state.driver = driver;
  if (was !== driver) {
    clearTimeout(state.stepTimer); state.held = 0; state.toggled = 0; link.axis = 0;
    $('forward').setAttribute('aria-pressed', 'false'); $('back').setAttribute('aria-pressed', 'false');
    if (driver) link.sendAxis();
  }
  const canTake = !driver && !link.watchOnly;
  $('take-control').hidden = !canTake;
  if (!canTake && $('take-dialog').open) $('take-dialog').close();
  $('s-role').textContent = driver ? 'Driving'
    : link.watchOnly ? 'Watching only (this page does not drive; you may press STOP)'
    : m.taken ? 'Watching: another station took control (you may press STOP or take control back)'
    : m.driver_present === false ? 'Watching (nobody drives: you may take control)'
    : 'Watching (another station drives; you may press STOP, or take control while the arm is at rest)';
  if (was && !driver && m.taken) say('Another station took control: this station now watches');
  if (!was && driver && state.claimed) say('This station drives now: let go of the input, then drive');
  state.claimed = false;
  questAnswerable();
}
$('take-control').onclick = () => $('take-dialog').showModal();
$('take-cancel').onclick = () => $('take-dialog').close();
$('take-confirm').onclick = () => { state.claimed = true; link.send({ type: 'claim', confirm: true }); $('take-dialog').close(); };

function showState(s) {
  const c = s.controller, f = s.safety;
  if (c) {
    $('s-controller').textContent = c.words + (c.reason ? ` (${c.reason})` : '');
    const ee = c.mode === 'end_effector';
    $('s-mode').textContent = ee && c.ee_axis ? `end-effector, moving along ${c.ee_axis}` : c.mode;
    $('ee-next').hidden = !ee;   // the end-effector baseline's mode button
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
  if (s.settings && JSON.stringify(s.settings) !== state.settingsJson) showSettings(s.settings);
  if (s.settings_problem !== undefined) $('set-problem').textContent = s.settings_problem;
  if (s.questionnaire !== undefined) showQuestionnaire(s.questionnaire);
}

// The station's settings (the robot PC's file): the fields are filled only when they change there, so
// a caregiver's typing is not overwritten by the next status; a new mode or device stops the arm.
function showSettings(st) {
  const old = state.settings;
  state.settings = st; state.settingsJson = JSON.stringify(st);
  if (old.action_mode !== st.action_mode || old.input_device !== st.input_device) stopDriving();
  $('set-speed').value = st.speed_scale;
  $('set-deadband').value = st.deadband ?? '';
  $('set-mode').value = st.action_mode; $('set-device').value = st.input_device;
  $('set-step').value = st.step_seconds ?? STEP_S; $('set-scan').value = st.scan_period ?? SCAN_S;
  for (const a of ['forward', 'back', 'stop']) $(`key-${a}`).value = st.keys[a].join(' ');
  $('estop').setAttribute('aria-keyshortcuts', st.keys.stop.join(' '));
  $('estop').querySelector('.hint').textContent = `(${st.keys.stop.join(', ')})`;
  $('forward').setAttribute('aria-keyshortcuts', st.keys.forward.join(' '));
  $('back').setAttribute('aria-keyshortcuts', st.keys.back.join(' '));
}

// ------------------------------------------------------------------ live view
const canvas = $('frame'), ctx = canvas.getContext('2d');
// Latest only here too: a frame that comes while one is decoded replaces the one waiting, so a busy
// page shows the newest frame and never decodes a backlog.
let decoding = false, waiting = null;
function onFrame(blob, meta) {
  if (waiting) state.skipped = (state.skipped || 0) + 1;
  waiting = [blob, meta];
  if (!decoding) drawFrames();
}
async function drawFrames() {
  decoding = true;
  while (waiting) {
    const [blob, meta] = waiting; waiting = null;
    try { drawFrame(await createImageBitmap(blob), meta); } catch (e) { /* a damaged frame: the next one */ }
  }
  decoding = false;
}
function drawFrame(bmp, meta) {
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
  else if (m === 'step') { clearTimeout(state.stepTimer); drive(dir); state.stepTimer = setTimeout(() => release(dir, true), 1000 * (state.settings.step_seconds ?? STEP_S)); }
  else { state.held = dir; drive(dir); }
}
function stopDriving() { clearTimeout(state.stepTimer); state.held = 0; state.toggled = 0; drive(0); }
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
$('ee-next').onclick = () => link.send({ type: 'ee_next' });

// keys: the caregiver's mapping (settings.keys: forward, back, stop; a dual switch types two of them).
// Forward and back work anywhere on the page but in a form field; a stop key works everywhere, except a
// letter or digit typed into a field. Space is the single switch when scanning is chosen.
const SCAN = ['forward', 'back', 'next', 'gripper', 'ee-next', 'take-control'];
function scanList() {   // the open dialog's buttons, else the questionnaire, else the scanned controls shown
  const dialog = document.querySelector('dialog[open]');
  if (dialog) return [...dialog.querySelectorAll('button')].map((b) => b.id);
  return questScan() || SCAN.filter((id) => !$(id).hidden);
}
function scanning() { return state.settings.input_device === 'switch1'; }
function keyAction(e) {
  const key = e.key.length === 1 ? e.key.toLowerCase() : e.key, keys = state.settings.keys || {};
  return ['stop', 'forward', 'back'].find((a) => (keys[a] || []).includes(key));
}
addEventListener('keydown', (e) => {
  const act = keyAction(e), inField = e.target.matches('select, input, textarea');
  if (act === 'stop' && !(inField && e.key.length === 1)) { e.preventDefault(); estop(); return; }
  if (inField || e.repeat) return;
  if (scanning() && e.key === ' ') { e.preventDefault(); const id = state.scanIds[state.scan];
    if (questSwitch(id)) return;
    if (id === 'forward' || id === 'back') press(id === 'forward' ? 1 : -1); else if (id) $(id).click(); return; }
  if (act) { e.preventDefault(); press(act === 'forward' ? 1 : -1); }
});
addEventListener('keyup', (e) => {
  if (scanning() && e.key === ' ') { const id = state.scanIds[state.scan]; if (id === 'forward' || id === 'back') release(0); return; }
  const act = keyAction(e);
  if (act === 'forward' || act === 'back') release(act === 'forward' ? 1 : -1);
});
function scanStep() {       // single-switch scanning: the highlight steps every scan_period while nothing is held
  armScan();
  if (!scanning()) { if (state.scan >= 0) { document.querySelectorAll('.scan').forEach((e) => e.classList.remove('scan')); state.scan = -1; } return; }
  if (state.held) return;
  let ids = scanList();
  if (ids.join() !== state.scanIds.join()) { state.scanIds = ids; state.scan = -1; }
  if (quest.group >= 0 && state.scan + 1 >= ids.length) {   // a round of a statement's numbers without a
    const i = quest.group; quest.group = -1; ids = scanList(); scanTo(ids, i); return;   // choice: back to it
  }
  scanTo(ids, (state.scan + 1) % ids.length);
}
function scanTo(ids, i) {   // highlight ids[i] now (a switch's choice moves it at once)
  document.querySelectorAll('.scan').forEach((e) => e.classList.remove('scan'));
  state.scanIds = ids; state.scan = i;
  if (ids[i]) $(ids[i]).classList.add('scan');
}
function armScan() { clearTimeout(state.scanTimer); state.scanTimer = setTimeout(scanStep, 1000 * (state.settings.scan_period ?? SCAN_S)); }
armScan();
function pollGamepad() {   // the Gamepad API: the first connected pad's left stick (up = toward the task)
  // Only a change of the stick drives (the buttons and keys keep working); a pad that goes away, or a
  // device that is no longer the gamepad, stops what the stick was doing.
  // Buttons act on a press (not while held): B (button 1) is STOP on any pad, whatever the device
  // setting; A (button 0) toggles the hand when the gamepad is the input device.
  let a = 0;
  const pad = [...(navigator.getGamepads ? navigator.getGamepads() : [])].find((p) => p && p.connected);
  const down = (i) => !!(pad && pad.buttons && pad.buttons[i] && pad.buttons[i].pressed);
  const stopNow = down(PAD_STOP), grasp = down(PAD_GRASP);
  if (stopNow && !state.padStop) estop();
  if (grasp && !state.padGrasp && state.settings.input_device === 'gamepad') link.send({ type: 'gripper' });
  state.padStop = stopNow; state.padGrasp = grasp;
  if (state.settings.input_device === 'gamepad') {
    const v = pad && pad.axes.length > 1 ? -pad.axes[1] : 0;
    a = Number.isFinite(v) && Math.abs(v) >= 0.15 ? +(Math.max(-1, Math.min(1, v)) * state.speed).toFixed(2) : 0;
  }
  if (a !== state.padAxis) { state.padAxis = a; link.setAxis(a);
    $('forward').setAttribute('aria-pressed', String(a > 0)); $('back').setAttribute('aria-pressed', String(a < 0)); }
  requestAnimationFrame(pollGamepad);
}
requestAnimationFrame(pollGamepad);

// ------------------------------------------------------------------ the questionnaire
// The study's questionnaire (the station's ~/questionnaire action), shown while it waits, answered by
// the driving page: one radio group (fieldset and legend) per statement, numbers with words for the
// ends. It is a part of the page, not a modal dialog: STOP and its key work as ever. Nothing is kept in
// the browser: a reload shows it again, empty, and only "Send answers" sends (the station checks the
// answers and refuses a second send). With a single switch the highlight steps through the statements
// and "Send answers"; a press on a statement steps through its numbers, a press on a number chooses it.
const quest = { shown: null, sent: null, group: -1 };
state.quest = quest;   // read by the browser tests
function showQuestionnaire(q) {
  const had = quest.shown;
  if (!q) {
    if (!had) return;
    quest.shown = null; quest.group = -1; $('questionnaire').hidden = true;
    $('q-status').textContent = quest.sent === had.id ? 'Thank you: your answers were sent.'
                                                      : 'The questionnaire was withdrawn.';
    return;
  }
  if (had && had.id === q.id) return;
  quest.shown = q; quest.sent = null; quest.group = -1;
  $('q-title').textContent = q.title;
  $('q-scale').textContent = `For each statement choose a number from ${q.min} (${q.min_label}) to ${q.max}`
    + ` (${q.max_label}). Every statement needs an answer.`;
  const items = q.statements.map((text, i) => {
    const fs = document.createElement('fieldset'); fs.id = `q-${i}`;
    const legend = document.createElement('legend'); legend.textContent = `${i + 1}. ${text}`;
    const row = document.createElement('div'); row.className = 'q-scale';
    for (let v = q.min; v <= q.max; v++) {
      const label = document.createElement('label'), input = document.createElement('input');
      label.id = `q-${i}-${v}`; input.type = 'radio'; input.name = `q-${i}`; input.value = String(v);
      const num = document.createElement('span'); num.textContent = String(v);
      label.append(input, num);
      const words = v === q.min ? q.min_label : v === q.max ? q.max_label : '';
      if (words) { const w = document.createElement('span'); w.className = 'q-words'; w.textContent = ` ${words}`; label.append(w); }
      row.append(label);
    }
    fs.append(legend, row);
    return fs;
  });
  $('q-items').replaceChildren(...items);
  $('questionnaire').hidden = false;
  questAnswerable();
  $('q-status').textContent = state.driver ? `A questionnaire is waiting: ${q.statements.length} statements.`
                                           : 'A questionnaire is waiting on the driving station.';
  if (state.driver && $('settings').hidden && !document.querySelector('dialog[open]')) $('q-h').focus();
}
function questAnswerable() {   // only the driving page answers; the others say so
  const answer = !!quest.shown && state.driver;
  $('q-form').hidden = !answer; $('q-watch').hidden = answer || !quest.shown;
}
function questScan() {
  if (!quest.shown || $('q-form').hidden || !$('settings').hidden) return null;
  if (quest.group >= 0) {
    return [...$(`q-${quest.group}`).querySelectorAll('label')].map((l) => l.id);
  }
  return [...quest.shown.statements.map((_, i) => `q-${i}`), 'q-submit'];
}
function questSwitch(id) {      // a single switch's press on the questionnaire's highlight
  const group = /^q-(\d+)$/.exec(id || ''), option = /^q-(\d+)-(\d+)$/.exec(id || '');
  if (group) { quest.group = +group[1]; scanTo(questScan(), 0); armScan(); return true; }
  if (option) {
    const input = $(id).querySelector('input');
    input.checked = true; input.dispatchEvent(new Event('change', { bubbles: true }));
    quest.group = -1;
    const ids = questScan(); scanTo(ids, Math.min(+option[1] + 1, ids.length - 1)); armScan();
    return true;
  }
  return false;
}
$('q-form').addEventListener('submit', (e) => {
  e.preventDefault();
  const q = quest.shown;
  if (!q || !state.driver) return;
  const answers = {};
  let missing = -1;
  q.statements.forEach((text, i) => {
    const checked = document.querySelector(`input[name="q-${i}"]:checked`);
    if (checked) answers[text] = Number(checked.value); else if (missing < 0) missing = i;
  });
  if (missing >= 0) {
    $('q-status').textContent = `Not sent: statement ${missing + 1} needs an answer (${q.statements[missing]}).`;
    if (!scanning()) document.querySelector(`input[name="q-${missing}"]`).focus();
    return;
  }
  if (!link.ws || link.ws.readyState !== WebSocket.OPEN) {   // kept on the page: send again once connected
    $('q-status').textContent = 'Not sent: not connected to the robot. Your answers stay here; send them again when connected.';
    return;
  }
  quest.sent = q.id;
  $('q-status').textContent = 'Sending your answers…';
  link.send({ type: 'answers', id: q.id, answers });
});
function questReply(m) {
  if (m.ok) return;   // the station hides the questionnaire: "thank you" then
  quest.sent = null;
  $('q-status').textContent = `Not sent: ${m.message}`;
}

// ------------------------------------------------------------------ stop
function estop() { state.estopSent = performance.now(); state.estopLatency = null; stopDriving(); link.send({ type: 'estop' }); say('STOP sent'); }
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
const num = (id) => ($(id).value.trim() === '' ? null : Number($(id).value));   // the station checks them
const keyList = (id) => $(id).value.split(/[\s,]+/).filter(Boolean);
$('set-save').onclick = () => {
  $('set-message').textContent = 'Saving…';
  link.send({ type: 'settings', values: {
    speed_scale: num('set-speed'), deadband: num('set-deadband'), action_mode: $('set-mode').value,
    input_device: $('set-device').value, step_seconds: num('set-step'), scan_period: num('set-scan'),
    keys: { forward: keyList('key-forward'), back: keyList('key-back'), stop: keyList('key-stop') } } });
};
