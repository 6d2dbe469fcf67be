// Small DOM helpers shared by the page's modules.
export const $ = (id) => document.getElementById(id);

// Text changes only when it differs: the page gets the nodes' state ~50 times a second, and rewriting
// an unchanged text makes a screen reader announce it again (a live region) or the page repaint.
export function setText(el, text) {
  if (el.textContent !== text) el.textContent = text;
}

export function setAttr(el, name, value) {
  if (el.getAttribute(name) !== value) el.setAttribute(name, value);
}

export function show(el, visible) {
  if (el.hidden === visible) el.hidden = !visible;
}
