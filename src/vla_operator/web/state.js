// What the arm does, for the state bar: one word, a sentence saying what to do, and the bar's look
// (its CSS class: colour with the word, never colour alone). The e-stop wins over everything the nodes
// say: while it is latched nothing reads "Ready" or "Moving", whatever the controller reports.

// vla_interfaces ControllerStatus and SafetyStatus codes (words.py has their words)
const C = { ACTIVE: 0, NEUTRAL: 1, WAITING_FOR_JOY: 2, NO_JOINT_STATES: 4, NO_OBJECT: 5, AWAITING_NEUTRAL: 9 };
const S = { REFLEX: 10, TEACHING: 11, AWAITING_ZERO: 12 };
const STOPPED_BY_SAFETY = new Set([1, 2, 6, 8, 9]);   // bad command, command timeout, state invalid, implausible

// {connected, ctrl, safety, driver, refused, held}: the link is up, the controller's and the bridge's
// status (null until they answer), this page drives, this page's held input was refused, the station
// holds all motion (the caregiver's stop_on_stale_view while the live view has stopped: motion_held).
// Returns [look, word, sentence].
export function armState({ connected, ctrl, safety, driver, refused, held }) {
  if (!connected) return ['offline', 'Offline', 'Not connected to the robot: the arm is stopped. Connecting again…'];
  if (safety && safety.estop) {
    return ['estop', 'E-stop', 'Emergency stop latched: the arm will not move. Choose “Release stop…” when it is safe.'];
  }
  if (held) return ['waiting', 'Held', HELD];
  if (!ctrl || !safety) return ['starting', 'Starting', 'Waiting for the robot’s nodes: this can take a minute.'];
  if (safety.code === S.REFLEX) return ['stopped', 'Stopped', 'The robot stopped itself (a reflex): it needs recovery.'];
  if (safety.code === S.TEACHING) return ['teaching', 'Teaching', 'Teaching mode: move the arm by hand; the input does nothing.'];
  if (refused) return ['letgo', 'Let go', 'Your input was not accepted: let go and press again.'];
  if (ctrl.code === C.AWAITING_NEUTRAL || safety.code === S.AWAITING_ZERO) {
    return ['letgo', 'Let go', 'Stopped: let go of the input, then press again to move.'];
  }
  if (ctrl.code === C.ACTIVE) {
    return ['moving', 'Moving', driver ? 'Moving with your input: let go to stop.' : 'Moving: another station drives.'];
  }
  if (STOPPED_BY_SAFETY.has(safety.code)) return ['stopped', 'Stopped', `${safety.words}.`];
  if (ctrl.code === C.NO_JOINT_STATES) return ['waiting', 'Waiting', 'Waiting for the arm’s joint states.'];
  if (ctrl.code === C.NO_OBJECT) return ['waiting', 'Waiting', 'Waiting to see the object: choose one, or Re-detect.'];
  if (ctrl.code === C.NEUTRAL || ctrl.code === C.WAITING_FOR_JOY) {
    return ['stopped', 'Stopped', driver ? 'At rest: hold “Toward the task (+)” to move.' : 'At rest.'];
  }
  return ['stopped', 'Stopped', `${ctrl.words}.`];
}

export const HELD = 'The live view has stopped (no new picture), so the arm is held until the view is back; '
  + 'then let go and press again.';

// The controller's row of the status list: its words, unless the e-stop holds the arm (then the
// controller's "Ready" or "Moving with your input" would be false).
export function controllerText(ctrl, safety) {
  if (safety && safety.estop) return 'Held by the emergency stop: the arm does not move';
  return ctrl.words + (ctrl.reason ? ` (${ctrl.reason})` : '');
}

// How the controller chose its object, in words (not its parameter names).
export function chosenBy(latchedBy) {
  if (!latchedBy) return '';
  if (latchedBy.startsWith('operator')) return 'you chose it';
  const rule = latchedBy.replace(/^goal_selection:\s*/, '');
  if (rule === 'highest_score') return 'chosen automatically: the surest detection';
  if (rule === 'nearest_to_ee') return 'chosen automatically: the nearest to the hand';
  return `chosen automatically: the ${objectName(rule)}`;
}

export function objectName(classId) { return String(classId).replaceAll('_', ' '); }
