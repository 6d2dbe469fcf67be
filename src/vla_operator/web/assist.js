// The controller's assistance on the page (its level, the goal it infers and how sure it is: the
// controller's status, vla_latent_controller/assistance.py): a line over the live view, a marker drawn on
// the goal's object in the picture, and the goal said in the state bar. The bar is a live region: it says
// a new goal once the controller has kept it for GOAL_SETTLE_MS (a goal that flickers for a moment between
// two close ones is not announced), never a change of confidence alone.
import { objectName } from './state.js';

export const GOAL_SETTLE_MS = 500;
const TASK_WORDS = { pick_place: 'pick and place' };
const MARK = '#ff2bd6';    // the goal's marker: a ring with a dot and its label (not the boxes' colours)

function on(c) { return !!c && !!c.assistance && c.assistance !== 'off'; }

// "bread/push_east" -> "the bread (push east)"
export function goalWords(goalTask) {
  const [cls, task = ''] = String(goalTask).split('/');
  const t = TASK_WORDS[task] ?? task.replaceAll('_', ' ');
  return t ? `the ${objectName(cls)} (${t})` : `the ${objectName(cls)}`;
}

export function sure(c) { return `${Math.round(100 * (Number(c.goal_confidence) || 0))} % sure`; }

// The live view's line ('' when the assistance is off)
export function assistText(c) {
  if (!on(c)) return '';
  const level = `Assistance ${c.assistance}`;
  return c.goal_task ? `${level}: goal ${goalWords(c.goal_task)}, ${sure(c)}` : `${level}: no goal inferred yet`;
}

// The state bar's sentence for the goal: a new goal once it has held GOAL_SETTLE_MS ('' when none)
export class GoalAnnouncer {
  constructor() { this.seen = ''; this.since = 0; this.said = ''; }

  update(c, now) {
    const goal = on(c) ? c.goal_task || '' : '';
    if (goal !== this.seen) { this.seen = goal; this.since = now; }
    if (goal !== this.said && now - this.since >= GOAL_SETTLE_MS) this.said = goal;
    return this.said ? `Goal inferred: ${goalWords(this.said)}.` : '';
  }
}

// The marker on the goal's object (its detection's centre, normalised image coordinates), with its
// confidence written beside it: shape and words, not colour alone.
export function drawGoal(ctx, c) {
  if (!on(c) || !c.goal_task || !Number.isFinite(c.goal_image_x) || !Number.isFinite(c.goal_image_y)) return;
  const w = ctx.canvas.width, x = c.goal_image_x * w, y = c.goal_image_y * ctx.canvas.height;
  const r = Math.max(8, w / 24), line = Math.max(3, w / 120), size = Math.max(10, Math.round(w / 32));
  for (const [colour, width] of [['#fff', line + 4], [MARK, line]]) {
    ctx.strokeStyle = colour; ctx.lineWidth = width;
    ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.stroke();
  }
  ctx.fillStyle = MARK;
  ctx.beginPath(); ctx.arc(x, y, r / 3, 0, 2 * Math.PI); ctx.fill();
  const label = `goal, ${sure(c)}`;
  ctx.font = `bold ${size}px system-ui, sans-serif`; ctx.textBaseline = 'top';
  // below the ring (the boxes' names are above their boxes), inside the picture
  const tw = ctx.measureText(label).width + 6, lx = Math.max(0, Math.min(x - tw / 2, w - tw));
  const ly = Math.min(y + r + line + 2, ctx.canvas.height - size - 6);
  ctx.fillRect(lx, ly, tw, size + 6);
  ctx.fillStyle = '#000';
  ctx.fillText(label, lx + 3, ly + 3);
}
