/* cellctl dashboard: building page elements, and the message line under the commands. */

export const $ = (id) => document.getElementById(id);

// el("p", { class: "muted", text: "..." }, ...children): attributes, then children (nodes or
// text; null, undefined and false are left out). `text` sets the text, `onclick` etc. a listener.
export function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  setAttrs(node, attrs);
  for (const c of children.flat(Infinity)) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : String(c));
  }
  return node;
}

const SVG_NS = "http://www.w3.org/2000/svg";
export function svg(tag, attrs, ...children) {
  const node = document.createElementNS(SVG_NS, tag);
  setAttrs(node, attrs);
  for (const c of children.flat(Infinity)) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : String(c));
  }
  return node;
}

function setAttrs(node, attrs) {
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k === "class") node.setAttribute("class", v);
    else if (k === "text") node.textContent = v;
    else if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v === true ? "" : String(v));
  }
}

export function setClass(node, cls, on) {
  node.classList.toggle(cls, Boolean(on));
}

export function showMessage(text, isError = false) {
  const m = $("message");
  m.textContent = text;
  setClass(m, "is-alarm", isError);
}
