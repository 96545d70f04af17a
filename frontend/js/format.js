// Formatting: times (Zurich, fleet clock or wall time said), numbers, DOM building, badges with
// an icon besides their colour, natural sort of ids, and in-place updates that keep focus.

export const TZ = "Europe/Zurich";
const zurich = new Intl.DateTimeFormat("sv-SE", { timeZone: TZ, year: "numeric", month: "2-digit", day: "2-digit", hour: "2-digit", minute: "2-digit", second: "2-digit" });
/** An ISO UTC time as Zurich local time "YYYY-MM-DD HH:MM:SS" (what Plotly plots as local). */
export const local = (iso) => (iso ? zurich.format(new Date(iso)) : "");
/** The two clocks a time can be on: the fleet's (the coaches' own clock: the demo's runs years
 *  behind) and the wall (when a person or the service did something). */
export const FLEET = "fleet clock, Zurich";
export const WALL = "wall time, Zurich";
export const fmt = (v, digits = 1) => (v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits));
export const pct = (v) => (v === null || v === undefined ? "–" : `${fmt(v, 1)} %`);
/** What each meter counts: the headline savings name theirs, the other meter's stand beside. */
export const METER_LABEL = { hvac: "HVAC units", hvac_and_floor: "HVAC + floor heating" };

const collator = new Intl.Collator("en", { numeric: true, sensitivity: "base" });
/** Natural order of ids ("D2" before "D10"); numbers by value, nulls first. */
export function naturalCompare(a, b) {
  if (a === b) return 0;
  if (a === null || a === undefined) return -1;
  if (b === null || b === undefined) return 1;
  if (typeof a === "number" && typeof b === "number") return a - b;
  if (typeof a === "boolean" || typeof b === "boolean") return Number(a) - Number(b);
  return collator.compare(String(a), String(b));
}

export const el = (tag, attrs = {}, ...children) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else if (k === "text") node.textContent = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c);
  return node;
};

/** Replaces `parent`'s children by `children`, changing only what differs: a child equal to its
 *  replacement stays, one of the same kind is updated in place (its attributes, then its own
 *  children alike), so that a refresh that changes a row's figures keeps the link or button in
 *  it that has the focus, and announces nothing new. Buttons and form fields are replaced whole
 *  when they differ (their listeners belong to the new ones). */
export function sync(parent, children) {
  if (parent.tagName === "TBODY") labelCells(parent.closest("table"), children);
  const old = [...parent.childNodes];
  children.forEach((child, i) => {
    const current = old[i];
    if (!current) parent.append(child);
    else if (!current.isEqualNode(child)) morph(parent, current, child);
  });
  for (const extra of old.slice(children.length)) extra.remove();
}

const WHOLE = new Set(["BUTTON", "INPUT", "SELECT", "TEXTAREA"]);

function morph(parent, current, next) {
  if (current.nodeName !== next.nodeName || WHOLE.has(next.nodeName)) {
    parent.replaceChild(next, current);
    return;
  }
  if (current.nodeType === Node.TEXT_NODE) {
    current.nodeValue = next.nodeValue;
    return;
  }
  for (const { name } of [...current.attributes]) if (!next.hasAttribute(name)) current.removeAttribute(name);
  for (const { name, value } of [...next.attributes]) if (current.getAttribute(name) !== value) current.setAttribute(name, value);
  sync(current, [...next.childNodes]);
}

/** Each cell of `rows` without a `data-label` gets its column's header text (a phone shows the
 *  rows as cards, each value under its label). */
function labelCells(table, rows) {
  const heads = table ? [...table.querySelectorAll("thead th")].map((th) => th.textContent.trim()) : [];
  if (!heads.length) return;
  for (const row of rows) {
    [...row.children].forEach((cell, i) => {
      if (!cell.hasAttribute("data-label") && heads[i] && !cell.hasAttribute("colspan")) cell.setAttribute("data-label", heads[i]);
    });
  }
}

/** A status badge: its colour and, drawn by style.css before the text, its icon (so that it is
 *  told apart without its colour; hidden from screen readers, the text says it). */
export function statusBadge(cls, text) {
  return el("span", { class: `badge ${cls}`, text });
}
export function badge(coach) {
  const label = coach.status === "override" && coach.override_until ? `override until ${local(coach.override_until).slice(11, 16)}` : coach.status;
  const wrap = el("span", {}, statusBadge(coach.status, label));
  if ((coach.status === "fallback" || coach.status === "disconnected") && coach.reason) wrap.append(el("span", { class: "reason", text: coach.reason }));
  return wrap;
}
/** The coach's decks against the comfort band now (its newest telemetry row), in words. */
export function comfortBadge(coach) {
  const c = coach.comfort;
  if (!c) return el("span", { class: "comfort-unknown", text: "–", title: "unknown: no telemetry in time, no T_rule or not in regular mode" });
  if (c.in_band) return el("span", { class: "comfort-in", text: "in band" });
  return statusBadge("comfort-out", `outside +${fmt(c.worst_excess_k, 2)} K (${c.decks_out.join(", ")})`);
}
/** The T_ref issued, and whether the coach receives it (a lost link: its HVAC holds T_rule). */
export function tRefCell(coach, digits = 2) {
  const wrap = el("span", {}, fmt(coach.t_ref_c, digits));
  if (coach.t_ref_applied === false) wrap.append(el("span", { class: "reason not-applied", text: "not applied: holds T_rule" }));
  return wrap;
}
export function kpi(label, value, id) {
  return el("div", { class: "kpi", ...(id ? { id } : {}) }, el("div", { class: "label", text: label }), el("div", { class: "value", text: value }));
}
/** "YYYY-MM-DDTHH:MM" in Zurich time → ISO UTC (finding the offset that round-trips). */
export function zurichToIso(value) {
  const guess = new Date(`${value}:00Z`);
  for (const offsetH of [1, 2, 0]) {
    const candidate = new Date(guess.getTime() - offsetH * 3600e3);
    if (local(candidate.toISOString()).startsWith(value.replace("T", " "))) return candidate.toISOString();
  }
  return guess.toISOString();
}
