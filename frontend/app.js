// trainclimate operator dashboard: fleet overview (savings, comfort, attention), the coaches'
// list, pair comparison (with the train's trial plan), coach detail, model health, audit log, API
// tokens (admins only). ES modules, no build step; Plotly.js is served by the backend (no CDN).
// This module signs in, routes (each view mounted with its own requests and timers, unmounted
// when left) and shows what the service is still preparing.
import { API, api, session } from "./js/api.js";
import { View } from "./js/view.js";
import * as audit from "./js/views/audit.js";
import * as coach from "./js/views/coach.js";
import * as fleet from "./js/views/fleet.js";
import * as model from "./js/views/model.js";
import * as overview from "./js/views/overview.js";
import * as tokens from "./js/views/tokens.js";
import * as train from "./js/views/train.js";

/** How often GET /health is asked while something is being prepared, and otherwise. [ms] */
const PREPARING_MS = 5_000;
const HEALTH_MS = 60_000;

// --- sign-in -------------------------------------------------------------------------------
async function signIn(token) {
  session.token = token;
  const me = await api("/me");
  session.me = me;
  sessionStorage.setItem("tc_token", token);
  document.body.classList.toggle("viewer", me.role === "viewer");
  document.body.classList.toggle("admin", me.role === "admin");
  document.getElementById("who").textContent = `${me.name} (${me.role})`;
  document.getElementById("signout").hidden = false;
}

function signOut() {
  sessionStorage.removeItem("tc_token");
  session.token = null;
  session.me = null;
  current?.unmount();
  current = null;
  document.body.classList.remove("admin");
  document.getElementById("who").textContent = "";
  document.getElementById("signout").hidden = true;
  showSignIn();
}
session.onUnauthorized = signOut;

function showSignIn(message = "") {
  const dialog = document.getElementById("signin");
  document.getElementById("signin-error").textContent = message;
  if (!dialog.open) dialog.showModal();
}

// --- what the service is still preparing (GET /health, no sign-in needed) --------------------
async function showPreparing() {
  const box = document.getElementById("preparing");
  let items = [];
  let storage = null;
  try {
    const health = await (await fetch(`${API}/health`)).json();
    items = health.preparing || [];
    storage = health.storage && health.storage.state === "error" ? health.storage : null;
  } catch {
    items = null;
  }
  if (items) {
    box.hidden = items.length === 0 && !storage;
    box.classList.toggle("failed", Boolean(storage) || items.some((p) => p.state === "failed"));
    const text = items.map((p) => (p.state === "failed"
      ? `Preparing the ${p.task} failed: ${p.detail}. The coaches stay on the rule-based setpoint T_rule.`
      : `Preparing the ${p.task}: ${p.stage}, ${Math.round(p.percent)} %. Until it is ready the coaches follow the rule-based setpoint T_rule; the layer takes over on its own.`))
      .concat(storage ? [`Storage error since ${new Date(storage.since).toLocaleString()} (wall time): ${storage.detail}. Writes are refused until it is resolved; reads go on.`] : []).join(" ");
    if (box.textContent !== text) box.textContent = text;
  }
  // often while something is prepared, rarely once nothing is
  setTimeout(showPreparing, items && (items.length || storage) ? PREPARING_MS : HEALTH_MS);
}

// --- router --------------------------------------------------------------------------------
const VIEWS = {
  overview: ["tpl-overview", overview],
  coaches: ["tpl-fleet", fleet],
  model: ["tpl-model", model],
  audit: ["tpl-audit", audit],
  tokens: ["tpl-tokens", tokens],
  train: ["tpl-train", train],
  coach: ["tpl-coach", coach],
};
let current = null;

function route() {
  if (tokenInAddress()) return;
  if (!session.me) return;
  const [, page, id] = (location.hash || "#/").split("/");
  let name = VIEWS[page] ? page : "overview";
  if ((name === "train" || name === "coach") && !id) name = "overview";
  if (name === "tokens" && session.me.role !== "admin") name = "overview"; // others never ask /tokens
  document.querySelectorAll("[data-nav]").forEach((a) => {
    const on = a.dataset.nav === name;
    a.classList.toggle("active", on);
    if (on) a.setAttribute("aria-current", "page"); else a.removeAttribute("aria-current");
  });
  current?.unmount();
  const [template, module] = VIEWS[name];
  const view = new View(template);
  current = view;
  view.refresh(() => module.mount(view, id && decodeURIComponent(id)));
}

// --- start ---------------------------------------------------------------------------------
document.getElementById("signin-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  try {
    await signIn(document.getElementById("token").value.trim());
    document.getElementById("signin").close();
    document.getElementById("token").value = "";
    route();
  } catch (err) {
    showSignIn(err.message);
  }
});
// Escape on the sign-in dialog: the page has nothing to show without a token, so the dialog
// stays, and says so
document.getElementById("signin").addEventListener("cancel", (event) => {
  event.preventDefault();
  document.getElementById("signin-error").textContent = "The dashboard needs a token: paste one to sign in.";
});
document.getElementById("signout").addEventListener("click", signOut);
window.addEventListener("hashchange", route);

/** A URL that carries a token in its fragment (`#token=…`, as `make demo` prints it: a fragment
 *  reaches no server log) signs in: the token is kept for the browser session like a pasted one
 *  and removed from the address bar at once. */
function tokenFromFragment() {
  const m = location.hash.match(/^#token=([^&]+)/);
  if (!m) return null;
  history.replaceState(null, "", `${location.pathname}${location.search}#/`);
  return decodeURIComponent(m[1]);
}

/** A `#token=` URL pasted into a tab already open (on the sign-in dialog or signed in): signs in
 *  with it. True when there was one. */
function tokenInAddress() {
  const token = tokenFromFragment();
  if (!token) return false;
  signIn(token).then(() => {
    const dialog = document.getElementById("signin");
    if (dialog.open) dialog.close();
    route();
  }, () => showSignIn("That token was not accepted; paste another one."));
  return true;
}

(async () => {
  showPreparing();
  const fromAddress = tokenFromFragment();
  session.token = fromAddress || session.token;
  if (!session.token) return showSignIn();
  try {
    await signIn(session.token);
    route();
  } catch {
    showSignIn("Your session has ended; sign in again.");
  }
})();
