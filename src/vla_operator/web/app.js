// The operator station's page: one screen with the state bar and STOP on top, the live view, and the
// drive controls at the bottom; the objects, the status, episodes and the study's questionnaire beside
// the view; the caregiver's settings on their own view. Driving by on-screen buttons, keys, a dual or
// single (scanning) switch, or a gamepad. Status in words: the state bar says what the arm does.
import { GoalAnnouncer } from './assist.js';
import { $, setAttr, setText, show } from './dom.js';
import { Link } from './link.js';
import { Questionnaire } from './quest.js';
import { Scanner, STOP_ID } from './scan.js';
import { armState, controllerText } from './state.js';
import { LiveView } from './view.js';

const STEP_S = 0.3;      // step mode: one press drives this long, then stops by itself (setting step_seconds)
const SCAN_S = 1.5;      // single switch: the highlight's time on each control (setting scan_period)
const PAD_GRASP = 0, PAD_STOP = 1;   // the standard gamepad's A (south) and B (east) buttons
const state = { driver: false, boxes: [], size: [640, 480], latched: null, speed: 0.6, settings: {}, settingsJson: '',
                held: 0, toggled: 0, stepTimer: 0, padAxis: 0, padNeutral: true, sent: {}, replies: {}, frames: 0,
                fpsT: performance.now(), fps: 0, age: null, refused: null, refusedHeld: false, claimed: false,
                connected: false, ctrl: null, safety: null, stale: '', motionHeld: '', goal: '', word: 'Starting' };
window.station = state;  // read by the browser tests and the benchmark

function say(text) { $('message').textContent = text; }

const link = new Link(onMessage, (blob, meta) => view.frame(blob, meta), (up) => {
  state.connected = up;
  setText($('connection'), up ? 'Connected to the robot' : 'Not connected: the arm is stopped');
  if (!up) letGo(false);
  render();
});
const view = new LiveView(state, (b) => { if (b) link.send({ type: 'select', by: 'pixel', x: b.cx, y: b.cy }); });
const scanner = new Scanner({ items: scanItems, period: () => state.settings.scan_period ?? SCAN_S,
                              paused: () => state.held !== 0, roundEnd: () => quest.roundEnd() });
const goals = new GoalAnnouncer();
const quest = new Questionnaire({ state, link, scanner, scanning });
state.quest = quest;   // read by the browser tests
state.scanner = scanner;

function onMessage(m) {
  if (m.type === 'hello' || m.type === 'role') setRole(m);
  else if (m.type === 'state') showState(m);
  else if (m.type === 'reply' && m.what === 'questionnaire') quest.reply(m);
  else if (m.type === 'reply' && m.what === 'settings') {
    $('set-message').textContent = m.ok ? `Settings ${m.message}` : `Not saved: ${m.message}`;
  } else if (m.type === 'reply') {
    state.replies[m.what] = performance.now() - (state.sent[m.what] ?? NaN);
    if (m.what === 'estop' && m.ok) state.estopLatency = performance.now() - state.estopSent;
    if (m.what !== 'estop' || !m.ok) say(`${m.what}: ${m.ok ? 'done' : 'refused'}${m.message ? ' – ' + m.message : ''}`);
  } else if (m.type === 'refused') {
    state.refused = m.reason;
    if (m.what === 'input') refusedInput(m.reason);
    else say(`Refused: ${m.reason}`);
    if (m.what === 'answers') quest.reply({ ok: false, message: m.reason });
  }
}

// One station drives; a watcher may take control (a confirmed dialog; the station refuses while the
// driver moves the arm). A change of role lets go of whatever this page held, without sending it: the
// new driver starts from a neutral input, so a key held through the change moves nothing.
function setRole(m) {
  const was = state.driver, driver = !!m.driver;
  state.driver = driver;
  if (was !== driver) {
    clearTimeout(state.stepTimer); state.held = 0; state.toggled = 0; link.axis = 0; pressedLook(0);
    if (driver) link.sendAxis();
  }
  const canTake = !driver && !link.watchOnly;
  show($('take-control'), canTake);
  if (!canTake && $('take-dialog').open) $('take-dialog').close();
  setText($('s-role'), driver ? 'Driving'
    : link.watchOnly ? 'Watching only (this page does not drive; you may press STOP)'
    : m.taken ? 'Watching: another station took control (you may press STOP or take control back)'
    : m.driver_present === false ? 'Watching (nobody drives: you may take control)'
    : 'Watching (another station drives; you may press STOP, or take control while the arm is at rest)');
  if (was && !driver && m.taken) say('Another station took control: this station now watches');
  if (!was && driver && state.claimed) say('This station drives now: let go of the input, then drive');
  state.claimed = false;
  quest.answerable();
  render();
}
$('take-control').onclick = () => $('take-dialog').showModal();
$('take-cancel').onclick = () => $('take-dialog').close();
$('take-confirm').onclick = () => { state.claimed = true; link.send({ type: 'claim', confirm: true }); $('take-dialog').close(); };

function showState(s) {
  const c = s.controller, f = s.safety;
  if (c) state.ctrl = c;
  if (f) state.safety = f;
  if (c || f) {
    if (state.ctrl) setText($('s-controller'), controllerText(state.ctrl, state.safety));
  }
  if (c) {
    const ee = c.mode === 'end_effector';
    setText($('s-mode'), ee && c.ee_axis ? `end-effector, moving along ${c.ee_axis}` : c.mode);
    show($('ee-next'), ee);   // the end-effector baseline's mode button
    state.latched = c.latched_class ? c : null;
    view.target(c);
    view.assist(c);
  }
  state.goal = goals.update(state.ctrl, performance.now());
  if (f) {
    setText($('s-safety'), f.words + (f.text ? ` (${f.text})` : ''));
    setText($('s-teaching'), f.teaching ? 'On' : 'Off');
    setAttr($('teaching'), 'aria-pressed', String(f.teaching));
  }
  if (s.gripper) setText($('s-gripper'), s.gripper.text || (s.gripper.holding ? `holding ${s.gripper.holding}` : '–'));
  showRecorder(s);
  if (s.settings && JSON.stringify(s.settings) !== state.settingsJson) showSettings(s.settings);
  if (s.settings_problem !== undefined) setText($('set-problem'), s.settings_problem);
  if (s.questionnaire !== undefined) quest.show(s.questionnaire);
  state.stale = view.stale(s);
  if (s.motion_held !== undefined) state.motionHeld = s.motion_held || '';
  render();
}

// Episodes only where a recorder answers (its status arrived): the teleop graph starts none.
function showRecorder(s) {
  show($('episodes'), !!s.recorder);
  if (s.recorder) setText($('s-recorder'), s.recorder.recording ? `Recording ${s.recorder.task}` : 'Not recording');
  if (s.tasks && $('task').options.length === 0) {
    for (const t of s.tasks) $('task').add(new Option(t, t));
  }
}

// The state bar: one word and what to do (announced: a live region, changed only when it changes), and
// the look of the whole page (a latched e-stop turns it red and says so).
function render() {
  const now = () => armState({ connected: state.connected, ctrl: state.ctrl, safety: state.safety,
                               driver: state.driver, refused: state.refusedHeld, held: !!state.motionHeld });
  let [look, word, detail] = now();
  if (letGoWhenTold(look)) [look, word, detail] = now();
  state.word = word;
  setText($('state-word'), word);
  const goal = ['E-stop', 'Offline', 'Starting'].includes(word) ? '' : state.goal;
  const stale = word === 'Held' ? '' : state.stale;
  setText($('state-detail'), [detail, stale, goal].filter(Boolean).join(' '));
  if (document.body.dataset.state !== look) document.body.dataset.state = look;
  const latched = look === 'estop';
  show($('release'), latched);
  if (!latched && $('release-dialog').open) $('release-dialog').close();
  setText($('estop').querySelector('.hint'), latched ? '(latched)' : `(${(state.settings.keys?.stop || ['Esc']).join(', ')})`);
  for (const id of ['back', 'forward']) setAttr($(id), 'aria-disabled', String(latched));
}

// The station's settings (the robot PC's file): the fields are filled only when they change there, so
// a caregiver's typing is not overwritten by the next status; a new mode or device stops the arm.
function showSettings(st) {
  const old = state.settings;
  state.settings = st; state.settingsJson = JSON.stringify(st);
  if (old.action_mode !== st.action_mode || old.input_device !== st.input_device) stopDriving();
  $('set-speed').value = st.speed_scale;
  $('set-deadband').value = st.deadband ?? '';
  $('set-assist').value = st.assistance ?? '';   // none yet: the controller has not answered
  $('set-mode').value = st.action_mode; $('set-device').value = st.input_device;
  $('set-step').value = st.step_seconds ?? STEP_S; $('set-scan').value = st.scan_period ?? SCAN_S;
  $('set-stale-stop').checked = !!st.stop_on_stale_view;
  for (const a of ['forward', 'back', 'stop']) $(`key-${a}`).value = st.keys[a].join(' ');
  $('estop').setAttribute('aria-keyshortcuts', st.keys.stop.join(' '));
  $('forward').setAttribute('aria-keyshortcuts', st.keys.forward.join(' '));
  $('back').setAttribute('aria-keyshortcuts', st.keys.back.join(' '));
  if (scanning()) scanner.start(); else scanner.stop();
  render();
}

$('prev').onclick = () => stepObject(-1);
$('next').onclick = () => stepObject(1);
$('redetect').onclick = () => link.send({ type: 'redetect' });
function stepObject(dir) {
  const n = state.boxes.length; if (!n) return;
  const cur = state.boxes.findIndex((b) => state.latched && b.class_id === state.latched.latched_class);
  const b = state.boxes[((cur < 0 ? (dir > 0 ? -1 : 0) : cur) + dir + n) % n];
  link.send({ type: 'select', by: 'pixel', x: b.cx, y: b.cy });
}

// ------------------------------------------------------------------ driving
document.querySelectorAll('input[name=speed]').forEach((r) => r.addEventListener('change', () => { state.speed = +r.value; }));
function mode() { return state.settings.action_mode || 'hold'; }
function press(dir) {             // dir: +1, -1
  state.refusedHeld = false;
  const m = mode();
  if (m === 'toggle') { state.toggled = state.toggled === dir ? 0 : dir; drive(state.toggled); }
  else if (m === 'step') { clearTimeout(state.stepTimer); drive(dir); state.stepTimer = setTimeout(() => release(dir, true), 1000 * (state.settings.step_seconds ?? STEP_S)); }
  else { state.held = dir; drive(dir); }
  render();
}
function stopDriving() { clearTimeout(state.stepTimer); state.held = 0; state.toggled = 0; drive(0); }
function release(dir, stepEnd = false) {
  if (state.refusedHeld) { state.refusedHeld = false; render(); }
  if (mode() === 'toggle') return;
  if (mode() === 'step' && !stepEnd) return;
  state.held = 0; drive(0);
}
function drive(dir) { link.setAxis(dir * state.speed); pressedLook(dir); }
function pressedLook(dir) {
  setAttr($('forward'), 'aria-pressed', String(dir > 0));
  setAttr($('back'), 'aria-pressed', String(dir < 0));
}

// The station refused this page's input. Nothing can move until a neutral (the station needs one), or
// the arm is not moving with it: stop what is held, send the neutral that lets the next press move,
// clear the pressed look, and say what to do. One late input while the arm moves with this page's input
// changes nothing (the next one, 40 ms later, counts): a busy machine does not stop a working drive.
function holding() { return state.held !== 0 || state.toggled !== 0 || state.padAxis !== 0 || link.axis !== 0; }
function refusedInput(reason) {
  if (/another station|watch/.test(reason)) { letGo(false); say(`Not moving: ${reason}.`); render(); return; }
  if (/^stopped: /.test(reason)) {   // the station holds all motion (a stopped live view): let go now
    if (holding()) letGo(true);
    say('Not moving: the live view has stopped, so the arm is held until it is back. Then let go and press again.');
    render(); return;
  }
  const needsNeutral = /neutral/.test(reason);
  if (!holding() || (!needsNeutral && state.word === 'Moving')) return;
  letGo(true);
  say(`Not moving: ${needsNeutral ? 'the station needs you to let go first'
                                  : 'your input arrived late (a busy computer or network)'}. Let go and press again.`);
  render();
}
// The controller or the bridge waits for a neutral while this page holds an input (a stop it did not
// choose): the page lets go itself, so the pressed look goes and the next press moves.
function letGoWhenTold(look) {
  if (look !== 'letgo' || state.refusedHeld || !holding()) return false;
  letGo(true);
  say('Stopped: let go and press again.');
  return true;
}
function letGo(mustRelease) {
  clearTimeout(state.stepTimer); state.held = 0; state.toggled = 0;
  if (state.padAxis !== 0) { state.padAxis = 0; state.padNeutral = false; }
  link.setAxis(0); pressedLook(0);
  if (mustRelease) state.refusedHeld = true;   // cleared when the person lets go (or presses anew)
}

for (const [id, dir] of [['forward', 1], ['back', -1]]) {
  const el = $(id);
  el.setAttribute('aria-pressed', 'false');
  el.addEventListener('pointerdown', (e) => { el.setPointerCapture(e.pointerId); press(dir); });
  for (const ev of ['pointerup', 'pointercancel', 'lostpointercapture']) el.addEventListener(ev, () => release(dir));
  el.addEventListener('keydown', (e) => { if ((e.key === ' ' || e.key === 'Enter') && !e.repeat && !scanning()) { e.preventDefault(); e.stopPropagation(); press(dir); } });
  el.addEventListener('keyup', (e) => { if ((e.key === ' ' || e.key === 'Enter') && !scanning()) release(dir); });
}
$('gripper').onclick = () => link.send({ type: 'gripper' });
$('ee-next').onclick = () => link.send({ type: 'ee_next' });

// ------------------------------------------------------------------ keys and the single switch
// keys: the caregiver's mapping (settings.keys: forward, back, stop; a dual switch types two of them).
// Forward and back work anywhere on the page but in a form field; a stop key works everywhere, except a
// letter or digit typed into a field. Space is the single switch when scanning is chosen.
const SCAN = ['forward', 'back', 'next', 'gripper', 'ee-next', 'take-control'];
function scanItems() {   // the open dialog's buttons, else the questionnaire, else the controls shown
  const dialog = document.querySelector('dialog[open]');
  if (dialog) return [...dialog.querySelectorAll('button')].map((b) => b.id);
  const q = quest.scanItems();
  if (q) return q;
  const shown = (id) => $(id).getClientRects().length > 0;   // on the page now (not hidden, nor its view)
  return [...(state.word === 'E-stop' ? ['release'] : []), ...SCAN.filter(shown)];
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
  if (scanning() && e.key === ' ') { e.preventDefault(); switchDown(); return; }
  if (act) { e.preventDefault(); press(act === 'forward' ? 1 : -1); }
});
addEventListener('keyup', (e) => {
  if (scanning() && e.key === ' ') { switchUp(); return; }
  const act = keyAction(e);
  if (act === 'forward' || act === 'back') release(act === 'forward' ? 1 : -1);
});
function switchDown() {   // the single switch closes on the highlighted control
  const id = scanner.current();
  if (!id) return;
  if (id === STOP_ID) { estop(); document.querySelectorAll('dialog[open]').forEach((d) => d.close()); }
  else if (quest.press(id)) return;
  else if (id === 'forward' || id === 'back') press(id === 'forward' ? 1 : -1);
  else $(id).click();
  scanner.keep();
}
function switchUp() {     // the switch opens: a held drive ends; the highlight stays on it a whole period
  const id = scanner.current();
  if (id === 'forward' || id === 'back') { release(0); scanner.keep(); }
}

// ------------------------------------------------------------------ the gamepad
// The Gamepad API: the first connected pad's left stick (up = toward the task). Only a change of the stick
// drives (the buttons and keys keep working); a pad that goes away, or a device that is no longer the
// gamepad, stops what the stick was doing; after a refusal the stick must come back to neutral first.
// Buttons act on a press (not while held): B (button 1) is STOP on any pad, whatever the device setting;
// A (button 0) toggles the hand when the gamepad is the input device.
function pollGamepad() {
  const pad = [...(navigator.getGamepads ? navigator.getGamepads() : [])].find((p) => p && p.connected);
  const down = (i) => !!(pad && pad.buttons && pad.buttons[i] && pad.buttons[i].pressed);
  const stopNow = down(PAD_STOP), grasp = down(PAD_GRASP), usePad = state.settings.input_device === 'gamepad';
  if (stopNow && !state.padStop) estop();
  if (grasp && !state.padGrasp && usePad) link.send({ type: 'gripper' });
  state.padStop = stopNow; state.padGrasp = grasp;
  let a = 0;
  if (usePad) {
    const v = pad && pad.axes.length > 1 ? -pad.axes[1] : 0;
    a = Number.isFinite(v) && Math.abs(v) >= 0.15 ? +(Math.max(-1, Math.min(1, v)) * state.speed).toFixed(2) : 0;
  }
  if (a === 0 && !state.padNeutral) { state.padNeutral = true; if (state.refusedHeld) { state.refusedHeld = false; render(); } }
  if (!state.padNeutral) a = 0;
  if (a !== state.padAxis) {
    if (a !== 0 && state.padAxis === 0) state.refusedHeld = false;
    state.padAxis = a; link.setAxis(a); pressedLook(a); render();
  }
  requestAnimationFrame(pollGamepad);
}
requestAnimationFrame(pollGamepad);

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
function settingsView(open) {   // the settings replace the driving view; the state bar and STOP stay
  $('settings').hidden = !open; $('operate').hidden = open; $('drive').hidden = open;
  $('view-toggle').setAttribute('aria-expanded', String(open));
  $(open ? 'settings-h' : 'view-toggle').focus();
}
$('settings-h').tabIndex = -1;
$('view-toggle').onclick = () => settingsView(true);
$('view-back').onclick = () => settingsView(false);
const num = (id) => ($(id).value.trim() === '' ? null : Number($(id).value));   // the station checks them
const keyList = (id) => $(id).value.split(/[\s,]+/).filter(Boolean);
$('set-save').onclick = () => {
  $('set-message').textContent = 'Saving…';
  link.send({ type: 'settings', values: {
    speed_scale: num('set-speed'), deadband: num('set-deadband'), assistance: $('set-assist').value || null,
    action_mode: $('set-mode').value,
    input_device: $('set-device').value, step_seconds: num('set-step'), scan_period: num('set-scan'),
    stop_on_stale_view: $('set-stale-stop').checked,
    keys: { forward: keyList('key-forward'), back: keyList('key-back'), stop: keyList('key-stop') } } });
};
render();
