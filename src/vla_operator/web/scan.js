// Single-switch scanning (the caregiver's input device "switch1"): a highlight steps through the controls
// every scan period and the switch (Space) acts on the highlighted one, held to drive.
// - STOP is first in every round and comes between any two controls: from any moment the highlight is
//   at most one step from STOP (a round of n controls takes 2n steps).
// - After an action the highlight stays on that control for a whole period, so a second press needs no
//   wait for the round to come back; while the switch holds a drive control the highlight waits.
// - The highlighted control is scrolled into view.
import { $ } from './dom.js';

export const STOP_ID = 'estop';

export class Scanner {
  // items(): the ids to scan now, STOP left out; period(): seconds per step; paused(): true while the
  // switch holds a control; roundEnd(): called when a round ends, true if it moved the highlight itself.
  constructor({ items, period, paused = () => false, roundEnd = () => false }) {
    Object.assign(this, { items, period, paused, roundEnd });
    this.ids = []; this.i = -1; this.onStop = false; this.active = false; this.timer = 0;
  }

  current() { return this.active ? (this.onStop ? STOP_ID : this.ids[this.i]) : undefined; }

  start() {
    if (this.active) return;
    this.active = true; this.ids = this.items(); this.i = -1; this.onStop = true;
    this.draw(); this.arm();
  }

  stop() {
    if (!this.active) return;
    this.active = false; clearTimeout(this.timer);
    document.querySelectorAll('.scan').forEach((e) => e.classList.remove('scan'));
  }

  // keep the highlight where it is for a whole period (after an action on it)
  keep() { if (this.active) { this.draw(); this.arm(); } }

  // highlight `id` of the list `ids` now (a choice that moves the highlight, as in the questionnaire)
  jump(ids, id) {
    this.ids = ids; this.i = Math.max(0, ids.indexOf(id)); this.onStop = ids.length === 0;
    this.keep();
  }

  arm() {
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.step(), 1000 * this.period());
  }

  step() {
    if (!this.active) return;
    if (this.paused()) { this.arm(); return; }
    const ids = this.items();
    if (ids.join() !== this.ids.join()) {     // another set of controls: a new round, STOP first
      this.ids = ids; this.i = -1;
      if (this.onStop) this.next(); else this.onStop = true;
    } else if (this.onStop) {
      if (this.i + 1 >= ids.length && this.i >= 0 && this.roundEnd()) { this.arm(); return; }
      this.next();
    } else {
      this.onStop = true;
    }
    this.draw(); this.arm();
  }

  next() {
    if (this.ids.length === 0) { this.onStop = true; return; }
    this.i = (this.i + 1) % this.ids.length; this.onStop = false;
  }

  draw() {
    const id = this.current();
    document.querySelectorAll('.scan').forEach((e) => { if (e.id !== id) e.classList.remove('scan'); });
    const el = id && $(id);
    if (!el) return;
    el.classList.add('scan');
    el.scrollIntoView({ block: 'nearest', inline: 'nearest' });
  }
}
