// API tokens (admins only): every token, revoked once confirmed. Times are wall time.
import { session } from "../api.js";
import { el, local, statusBadge } from "../format.js";

/** Who revoked a token, by token id, from the audit log (`token.revoke`, target `token:ID`);
 *  looked up once per revoked token (a revocation is final); null if the log has no entry. */
const revokers = new Map();

export async function mount(view) {
  const error = view.$("#tokens-error");

  async function load() {
    try {
      const tokens = await view.api("/tokens");
      await findRevokers(view, tokens);
      if (view.left) return;
      drawTokens(view, tokens, revoke);
    } catch (err) {
      if (!view.left) error.textContent = `Loading the tokens failed: ${err.message}`;
    }
  }

  async function revoke(token) {
    const question = `Revoke the ${token.role} token ${token.prefix}… of ${token.user}? ` +
      "It stops working at once (every request with it gets 401); this cannot be undone.";
    if (!window.confirm(question)) return;
    error.textContent = "";
    try {
      await view.api(`/tokens/${token.id}`, { method: "DELETE" });
    } catch (err) {
      error.textContent = `Revoking ${token.prefix}… of ${token.user} failed: ${err.message}`;
      return;
    }
    await load();
  }

  view.$("#tokens-refresh").addEventListener("click", () => {
    error.textContent = "";
    load();
  });
  await load();
}

async function findRevokers(view, tokens) {
  const unknown = tokens.filter((t) => t.revoked_at && !revokers.has(t.id));
  await Promise.all(unknown.map(async (t) => {
    const [entry] = await view.api(`/audit?target=${encodeURIComponent(`token:${t.id}`)}&limit=1`);
    revokers.set(t.id, entry && entry.action === "token.revoke" ? entry.user : null);
  }));
}

function tokenStatus(token, now) {
  if (token.revoked_at) return "revoked";
  if (token.expires_at && new Date(token.expires_at).getTime() <= now) return "expired";
  return "active";
}

/** Whether this is the token the dashboard is signed in with (its user and prefix match). */
function isCurrentToken(token) {
  return token.user === session.me.name && session.token.startsWith(token.prefix);
}

function drawTokens(view, tokens, revoke) {
  const now = Date.now();
  const minute = (iso) => local(iso).slice(0, 16);
  view.$("#tokens tbody").replaceChildren(...(tokens.length ? tokens.map((t) => {
    const status = tokenStatus(t, now);
    const expired = t.expires_at && new Date(t.expires_at).getTime() <= now;
    const by = revokers.get(t.id);
    return el("tr", { "data-token": t.id, "data-status": status },
      el("td", { text: t.user }),
      el("td", { class: "mono", text: `${t.prefix}…` }),
      el("td", { text: t.role }),
      el("td", { text: t.coaches ? t.coaches.join(", ") : "–" }),
      el("td", { class: "when", text: minute(t.created_at) }),
      el("td", { class: expired ? "when expired" : "when", text: t.expires_at ? `${minute(t.expires_at)}${expired ? " (expired)" : ""}` : "never" }),
      el("td", { text: t.revoked_at ? `${minute(t.revoked_at)}${by ? ` by ${by}` : ""}` : "–" }),
      el("td", {}, statusBadge(status, status)),
      el("td", {}, tokenAction(t, status, revoke)));
  }) : [el("tr", {}, el("td", { text: "no tokens" }))]));
}

function tokenAction(token, status, revoke) {
  if (status !== "active") return "";
  if (isCurrentToken(token)) {
    return el("span", { class: "hint", text: "your session", title: "the token you are signed in with: revoke it from another admin session" });
  }
  const button = el("button", { class: "secondary", text: "Revoke" });
  button.addEventListener("click", () => revoke(token));
  return button;
}
