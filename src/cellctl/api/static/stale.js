/* cellctl dashboard: nothing to operate on stale data. While the page hears nothing from the cell
   controller (status.js decides when that is) every button, field and list on the page is disabled
   and a note says why; on recovery exactly those it disabled are enabled again (the views then
   refresh and set their own rules, e.g. the commands the state allows). Runs on every live tick,
   so controls a view draws while the data is stale are caught too. */

import { readsNeedToken } from "./api.js";
import { $ } from "./dom.js";
import { clock } from "./format.js";

const CONTROLS = "button, input, select, textarea";
// Kept on while the cell answers reads 401: the data comes back only with a token (the cell is there).
const TOKEN_FORM = "#token-form";

export function applyStale(stale, lastMessageAt, ageS) {
  const note = $("stale-note");
  if (!stale) {
    for (const n of document.querySelectorAll("[data-stale-off]")) {
      n.disabled = false;
      delete n.dataset.staleOff;
    }
    note.hidden = true;
    return;
  }
  const needToken = readsNeedToken();
  for (const n of document.querySelectorAll(CONTROLS)) {
    if (needToken && n.closest(TOKEN_FORM)) {
      if (n.dataset.staleOff) n.disabled = false;
      delete n.dataset.staleOff;
      continue;
    }
    if (n.disabled) continue;
    n.disabled = true;
    n.dataset.staleOff = "1";
  }
  const age = Math.round(ageS);
  const text = lastMessageAt
    ? `Commands and forms are off: no data from the cell controller since ${clock(new Date(lastMessageAt).toISOString())} (${age} s ago). They come back by themselves when the data does.`
    : "Commands and forms are off until the first data from the cell controller arrives.";
  const ask = needToken ? " The cell controller answers only with a valid token: enter the operator token." : "";
  if (note.textContent !== text + ask) note.textContent = text + ask;
  note.hidden = false;
}
