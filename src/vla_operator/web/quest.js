// The study's questionnaire (the station's ~/questionnaire action), shown while it waits, answered by
// the driving page: one radio group (fieldset and legend) per statement, numbers with words for the
// ends. It is a part of the page, not a modal dialog: STOP and its key work as ever. Nothing is kept in
// the browser: a reload shows it again, empty, and only "Send answers" sends (the station checks the
// answers and refuses a second send). With a single switch the highlight steps through the statements
// and "Send answers"; a press on a statement steps through its numbers, a press on a number chooses it.
import { $, setText } from './dom.js';

export class Questionnaire {
  // page: {state, link, scanner, scanning()}
  constructor(page) {
    this.page = page; this.shown = null; this.sent = null; this.group = -1;
    $('q-form').addEventListener('submit', (e) => { e.preventDefault(); this.submit(); });
  }

  show(q) {
    const had = this.shown, s = this.page.state;
    if (!q) {
      if (!had) return;
      this.shown = null; this.group = -1; $('questionnaire').hidden = true;
      $('q-status').textContent = this.sent === had.id ? 'Thank you: your answers were sent.'
                                                       : 'The questionnaire was withdrawn.';
      return;
    }
    if (had && had.id === q.id) return;
    this.shown = q; this.sent = null; this.group = -1;
    $('q-title').textContent = q.title;
    $('q-scale').textContent = `For each statement choose a number from ${q.min} (${q.min_label}) to ${q.max}`
      + ` (${q.max_label}). Every statement needs an answer.`;
    $('q-items').replaceChildren(...q.statements.map((text, i) => statement(q, text, i)));
    $('questionnaire').hidden = false;
    this.answerable();
    $('q-status').textContent = s.driver ? `A questionnaire is waiting: ${q.statements.length} statements.`
                                         : 'A questionnaire is waiting on the driving station.';
    if (s.driver && $('settings').hidden && !document.querySelector('dialog[open]')) {
      $('q-h').scrollIntoView({ block: 'start' }); $('q-h').focus();
    }
  }

  answerable() {   // only the driving page answers; the others say so
    const answer = !!this.shown && this.page.state.driver;
    $('q-form').hidden = !answer; $('q-watch').hidden = answer || !this.shown;
  }

  // the controls a single switch scans while it waits (null: none)
  scanItems() {
    if (!this.shown || $('q-form').hidden || !$('settings').hidden) return null;
    if (this.group >= 0) return [...$(`q-${this.group}`).querySelectorAll('label')].map((l) => l.id);
    return [...this.shown.statements.map((_, i) => `q-${i}`), 'q-submit'];
  }

  // a round of a statement's numbers without a choice: back to the statement
  roundEnd() {
    if (this.group < 0) return false;
    const g = this.group; this.group = -1;
    this.page.scanner.jump(this.scanItems(), `q-${g}`);
    return true;
  }

  // a single switch's press on the highlighted `id`: true if it was the questionnaire's
  press(id) {
    const group = /^q-(\d+)$/.exec(id || ''), option = /^q-(\d+)-(\d+)$/.exec(id || '');
    const scanner = this.page.scanner;
    if (group) { this.group = +group[1]; const ids = this.scanItems(); scanner.jump(ids, ids[0]); return true; }
    if (!option) return false;
    const input = $(id).querySelector('input');
    input.checked = true; input.dispatchEvent(new Event('change', { bubbles: true }));
    this.group = -1;
    const ids = this.scanItems();
    scanner.jump(ids, ids[Math.min(+option[1] + 1, ids.length - 1)]);
    return true;
  }

  submit() {
    const q = this.shown, { state, link } = this.page;
    if (!q || !state.driver) return;
    const answers = {};
    let missing = -1;
    q.statements.forEach((text, i) => {
      const checked = document.querySelector(`input[name="q-${i}"]:checked`);
      if (checked) answers[text] = Number(checked.value); else if (missing < 0) missing = i;
    });
    if (missing >= 0) {
      $('q-status').textContent = `Not sent: statement ${missing + 1} needs an answer (${q.statements[missing]}).`;
      if (!this.page.scanning()) document.querySelector(`input[name="q-${missing}"]`).focus();
      return;
    }
    if (!link.ws || link.ws.readyState !== WebSocket.OPEN) {   // kept on the page: send again once connected
      $('q-status').textContent = 'Not sent: not connected to the robot. Your answers stay here; send them again when connected.';
      return;
    }
    this.sent = q.id;
    $('q-status').textContent = 'Sending your answers…';
    link.send({ type: 'answers', id: q.id, answers });
  }

  reply(m) {
    if (m.ok) return;   // the station hides the questionnaire: "thank you" then
    this.sent = null;
    setText($('q-status'), `Not sent: ${m.message}`);
  }
}

function statement(q, text, i) {
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
}
