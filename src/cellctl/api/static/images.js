/* cellctl dashboard: images read with the operator token. An <img src> cannot send the token, so
   with [api] open_reads = false the page fetches each image (getBlob) and shows it from a blob: URL.
   Each blob URL is revoked once its image has loaded or failed (the decoded picture stays shown),
   or when a newer image replaces it, so the page holds no blob for long. A link marked
   data-token-open (a full-size image) opens the same way in a new tab while a token is set. */

import { getBlob, readsNeedToken, token } from "./api.js";
import { el, showMessage } from "./dom.js";
import { on } from "./state.js";

const pending = new WeakMap(); // img -> its blob URL not yet revoked
const OPENED_REVOKE_MS = 60_000; // a full-size image opened in a tab has long loaded by then

function release(img) {
  const url = pending.get(img);
  if (url === undefined) return;
  URL.revokeObjectURL(url);
  pending.delete(img);
}

// The URL `img` shows or is loading ("" after a failure, so the next render tries again); compare
// with this, not with img.src (a blob: URL).
export function shownUrl(img) {
  return img.dataset.failed ? "" : img.dataset.src || "";
}

function failed(img, err) {
  release(img);
  img.removeAttribute("src");
  const needToken = readsNeedToken();
  img.dataset.failed = needToken ? "token" : "error";
  img.title = needToken ? "This image needs the operator token: enter it above." : `Could not load the image (${err.message}).`;
  img.dispatchEvent(new Event("error"));
}

function show(img, blob) {
  release(img);
  const blobUrl = URL.createObjectURL(blob);
  pending.set(img, blobUrl);
  const settled = new AbortController();
  const done = () => {
    settled.abort();
    if (pending.get(img) === blobUrl) release(img);
  };
  img.addEventListener("load", done, { signal: settled.signal });
  img.addEventListener("error", done, { signal: settled.signal });
  img.removeAttribute("title");
  img.src = blobUrl;
}

// Shows the image at `url` in `img`; a newer call for the same img wins over one still loading. On
// failure the img gets no src, data-failed ("token" when the cell wants a token) and a title that
// says why, and fires "error" as an <img> that failed to load would.
export async function showImage(img, url) {
  img.dataset.src = url;
  delete img.dataset.failed;
  try {
    const blob = await getBlob(url);
    if (img.dataset.src === url) show(img, blob);
  } catch (err) {
    if (img.dataset.src === url) failed(img, err);
  }
}

// Shows nothing in `img` (and drops what it was loading).
export function clearImage(img) {
  delete img.dataset.src;
  delete img.dataset.failed;
  release(img);
  img.removeAttribute("src");
}

// A new <img> showing `url` (read with the token); `attrs` as for el().
export function tokenImage(url, attrs) {
  const img = el("img", attrs);
  showImage(img, url);
  return img;
}

// Once a token is entered, the images refused for want of one load again.
on("token", (set) => {
  if (!set) return;
  for (const img of document.querySelectorAll("img[data-failed='token']")) showImage(img, img.dataset.src);
});

// Opens `url` in a new tab, read with the token; the tab is opened at once (in the click) so that
// no popup blocker stops it, and shows the image from a blob: URL once it is in.
async function openWithToken(url) {
  const tab = window.open("", "_blank");
  try {
    const blobUrl = URL.createObjectURL(await getBlob(url));
    setTimeout(() => URL.revokeObjectURL(blobUrl), OPENED_REVOKE_MS);
    if (!tab) throw new Error("the browser blocked the new tab");
    tab.opener = null;
    tab.location.href = blobUrl;
  } catch (err) {
    if (tab) tab.close();
    showMessage(`Could not open the image: ${err.message}`, true);
  }
}

document.addEventListener("click", (ev) => {
  const a = ev.target instanceof Element ? ev.target.closest("a[data-token-open]") : null;
  if (!a || !token() || ev.defaultPrevented || ev.button !== 0 || ev.ctrlKey || ev.metaKey || ev.shiftKey) return;
  ev.preventDefault();
  openWithToken(a.href);
});
