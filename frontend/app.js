// trainclimate operator dashboard: fleet overview (savings, comfort, attention), the coaches'
// list, pair comparison (with the train's trial plan), coach detail, model health, audit log, API
// tokens (admins only).
// Plain JavaScript, no build step; Plotly.js is served by the backend (no CDN).
"use strict";

const API = "/api/v1";
const TZ = "Europe/Zurich";
const REFRESH_MS = 5000;
const DECKS = ["up", "mid", "low"];
// Okabe–Ito colours: distinguishable with the common colour-vision deficiencies
const DECK_COLOUR = { up: "#D55E00", mid: "#009E73", low: "#0072B2" };
const COLOUR = { ref: "#000000", band: "#8c8c8c", amb: "#CC79A7", ghi: "#E69F00", act: "#009E73", deact: "#555555", savings: "#56B4E9" };
const SOURCE_COLOUR = { ddpc: "#009E73", rule: "#8c8c8c", override: "#5a32a3", fallback: "#b42318" };

const state = { token: sessionStorage.getItem("tc_token"), me: null, timer: null, sort: { key: "id", dir: 1 } };

// --- API -----------------------------------------------------------------------------------
class ApiError extends Error {
  constructor(status, detail) { super(typeof detail === "string" ? detail : formatDetail(detail)); this.status = status; }
}

function formatDetail(detail) {
  if (Array.isArray(detail)) {
    return detail.map((d) => `${(d.loc || []).filter((x) => x !== "body").join(".")}: ${d.msg}`).join("; ");
  }
  return JSON.stringify(detail);
}

async function api(path, options = {}) {
  const headers = { Authorization: `Bearer ${state.token}` };
  if (options.body) headers["Content-Type"] = "application/json";
  const reply = await fetch(API + path, { ...options, headers });
  const body = reply.headers.get("content-type")?.includes("json") ? await reply.json() : null;
  if (reply.status === 401) { signOut(); throw new ApiError(401, body?.detail || "not signed in"); }
  if (!reply.ok) throw new ApiError(reply.status, body?.detail ?? reply.statusText);
  return body;
}

// --- formatting ----------------------------------------------------------------------------
const zurich = new Intl.DateTimeFormat("sv-SE", { timeZone: TZ, year: "numeric", month: "2-digit", day: "2-digit", hour: "2-digit", minute: "2-digit", second: "2-digit" });
/** An ISO UTC time as Zurich local time "YYYY-MM-DD HH:MM:SS" (what Plotly plots as local). */
const local = (iso) => (iso ? zurich.format(new Date(iso)) : "");
const fmt = (v, digits = 1) => (v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits));
const el = (tag, attrs = {}, ...children) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else if (k === "text") node.textContent = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c);
  return node;
};
function badge(coach) {
  const label = coach.status === "override" && coach.override_until ? `override until ${local(coach.override_until).slice(11, 16)}` : coach.status;
  const span = el("span", { class: `badge ${coach.status}`, text: label });
  const wrap = el("span", {}, span);
  if ((coach.status === "fallback" || coach.status === "disconnected") && coach.reason) wrap.append(el("span", { class: "reason", text: coach.reason }));
  return wrap;
}
/** The coach's decks against the comfort band now (its newest telemetry row), in words. */
function comfortBadge(coach) {
  const c = coach.comfort;
  if (!c) return el("span", { class: "comfort-unknown", text: "–", title: "unknown: no telemetry in time, no T_rule or not in regular mode" });
  if (c.in_band) return el("span", { class: "comfort-in", text: "in band" });
  return el("span", { class: "badge comfort-out", text: `outside +${fmt(c.worst_excess_k, 2)} K (${c.decks_out.join(", ")})` });
}
/** The T_ref issued, and whether the coach receives it (a lost link: its HVAC holds T_rule). */
function tRefCell(coach, digits = 2) {
  const wrap = el("span", {}, fmt(coach.t_ref_c, digits));
  if (coach.t_ref_applied === false) wrap.append(el("span", { class: "reason not-applied", text: "not applied: holds T_rule" }));
  return wrap;
}
function kpi(label, value, id) {
  return el("div", { class: "kpi", ...(id ? { id } : {}) }, el("div", { class: "label", text: label }), el("div", { class: "value", text: value }));
}

// --- sign-in -------------------------------------------------------------------------------
async function signIn(token) {
  state.token = token;
  const me = await api("/me");
  state.me = me;
  sessionStorage.setItem("tc_token", token);
  document.body.classList.toggle("viewer", me.role === "viewer");
  document.body.classList.toggle("admin", me.role === "admin");
  document.getElementById("who").textContent = `${me.name} (${me.role})`;
  document.getElementById("signout").hidden = false;
}

function signOut() {
  sessionStorage.removeItem("tc_token");
  state.token = null;
  state.me = null;
  document.body.classList.remove("admin");
  document.getElementById("who").textContent = "";
  document.getElementById("signout").hidden = true;
  showSignIn();
}

function showSignIn(message = "") {
  const dialog = document.getElementById("signin");
  document.getElementById("signin-error").textContent = message;
  if (!dialog.open) dialog.showModal();
}

// --- what the service is still preparing (GET /health, no sign-in needed) --------------------
async function showPreparing() {
  const box = document.getElementById("preparing");
  let health;
  try {
    health = await (await fetch(`${API}/health`)).json();
  } catch {
    return;
  }
  const items = health.preparing || [];
  const storage = health.storage && health.storage.state === "error" ? health.storage : null;
  box.hidden = items.length === 0 && !storage;
  box.classList.toggle("failed", Boolean(storage) || items.some((p) => p.state === "failed"));
  box.textContent = items.map((p) => (p.state === "failed"
    ? `Preparing the ${p.task} failed: ${p.detail}. The coaches stay on the rule-based setpoint T_rule.`
    : `Preparing the ${p.task}: ${p.stage}, ${Math.round(p.percent)} %. Until it is ready the coaches follow the rule-based setpoint T_rule; the layer takes over on its own.`))
    .concat(storage ? [`Storage error since ${new Date(storage.since).toLocaleString()}: ${storage.detail}. Writes are refused until it is resolved; reads go on.`] : []).join(" ");
}
showPreparing();
setInterval(showPreparing, REFRESH_MS);

// --- router --------------------------------------------------------------------------------
function mount(templateId) {
  const view = document.getElementById("view");
  view.replaceChildren(document.getElementById(templateId).content.cloneNode(true));
  return view;
}

function every(ms, fn) {
  clearInterval(state.timer);
  state.timer = setInterval(() => fn().catch(report), ms);
  return fn().catch(report);
}

function report(err) {
  if (err instanceof ApiError && err.status === 401) return;
  console.warn(err);
}

async function route() {
  if (!state.me) return;
  const [, page, id] = (location.hash || "#/").split("/");
  document.querySelectorAll("[data-nav]").forEach((a) => a.classList.toggle("active", a.dataset.nav === (page || "overview")));
  clearInterval(state.timer);
  if (page === "train" && id) return showTrain(decodeURIComponent(id));
  if (page === "coach" && id) return showCoach(decodeURIComponent(id));
  if (page === "coaches") return showFleet();
  if (page === "model") return showModel();
  if (page === "audit") return showAudit();
  if (page === "tokens" && state.me.role === "admin") return showTokens(); // others never ask /tokens
  return showOverview();
}

// --- fleet overview: savings, comfort and what needs attention -----------------------------
const PLOT_CONFIG = { responsive: true, displaylogo: false };
const KIND_LABEL = { stale: "stale", disconnected: "disconnected", fallback: "fallback", override: "override", comfort: "comfort", costing_energy: "costs energy" };

async function showOverview() {
  const view = mount("tpl-overview");
  let summary = null;
  const drawTrains = () => summary && drawTrainFigures(view, summary);
  view.querySelector("#train-sort").addEventListener("change", drawTrains);
  view.querySelector("#hours").addEventListener("change", () => refresh().catch(report));
  async function refresh() {
    const hours = view.querySelector("#hours").value;
    const [s, health, coaches] = await Promise.all([api(`/fleet/summary?hours=${hours}`), modelHealth(hours), api("/coaches")]);
    summary = s;
    drawFeedDown(view.querySelector("#feed-down"), coaches);
    const end = s.trains.map((t) => t.end).sort().pop();
    view.querySelector("#overview-clock").textContent = end ? `fleet clock ${local(end)} (Zurich)` : "";
    drawFleetKpis(view.querySelector("#fleet-kpis"), s, health);
    drawModelFlag(view.querySelector("#model-flag"), health);
    drawEnergy(view.querySelector("#energy-figure"), s);
    drawTrains();
    drawAttention(view.querySelector("#attention tbody"), s.attention);
    view.querySelector("#by-status").replaceChildren(...Object.entries(s.coaches_by_status).map(([status, n]) =>
      el("a", { href: "#/coaches", class: "status-count", "data-status": status }, el("span", { class: `badge ${status}`, text: status }), el("span", { text: ` ${n}` }))));
  }
  await every(2 * REFRESH_MS, refresh);
}

/** The active model's health, or null while there is none (the first start prepares it). */
async function modelHealth(hours) {
  const active = (await api("/models")).find((m) => m.active);
  return active ? api(`/models/${active.version}/health?hours=${hours}`) : null;
}

/** What each meter counts: the headline savings name theirs, the other meter's stand beside. */
const METER_LABEL = { hvac: "HVAC units", hvac_and_floor: "HVAC + floor heating" };

function pct(v) {
  return v === null || v === undefined ? "–" : `${fmt(v, 1)} %`;
}

// --- savings with their uncertainty (the trial estimate of a pair, pooled for the fleet) -----
/** The coaches' colours where the pair's chart says which coach ran the layer (≥ 3:1 on white,
 *  told apart with the common colour-vision deficiencies; each run is labelled too). */
const COACH_SHADE = ["#332288", "#994F00"];
const NEITHER_SHADE = "#6b6b6b";
const EXCLUDED_SHADE = "#b42318";
/** The per-train savings bars: with a 95 % interval solid, without one hatched. */
const BAR = { solid: "#0072B2", light: "#dcebf5", whisker: "#1b1f24" };
/** Why a window does not count, in words (the API's `excluded_reason`). */
const EXCLUDED_REASON = {
  disconnected: "a coach disconnected",
  override: "an operator's override",
  missing_data: "data missing",
  no_setpoint: "no setpoint",
  preparing: "model being prepared",
  fallback: "DDPC fallback",
  not_regular: "HVAC not in regular mode",
  mixed_roles: "roles mixed in the window",
  plan_switch: "lead-in after a plan switch",
  reference: "reference: both coaches on T_rule",
};
const NO_WINDOWS = "no comparable windows yet";

/** Why a figure has no interval, in words (from its estimator and `savings_ci95_reason`). */
function noIntervalWords(f) {
  const why = f.savings_ci95_reason || "";
  if (f.estimator === "fixed_naive") {
    return why.startsWith("fewer than a day") ? "confounded with the coaches: less than a day's windows" : "confounded with the coaches: fixed plan";
  }
  const few = why.match(/^fewer than (\d+) days/);
  if (few) {
    const groups = f.estimator === "fixed_reference" ? "activated or on reference" : "with each coach activated";
    return `fewer than ${few[1]} days ${groups}: no interval yet`;
  }
  if (why === "no train has an interval yet") return "no interval: no train has one yet";
  if (why === "no day-to-day spread") return "no day-to-day spread: no interval";
  if (why === "the bootstrap is degenerate") return "no interval: the days' spread is degenerate";
  return why || "no interval";
}

/** A savings figure's parts: the value ("5.6 %"), its interval ("(95 % CI 2.1 to 9.0)") and what
 *  qualifies it (not yet distinguishable from zero, or why there is no interval); `none` when no
 *  window counted (never 0.0 % then). */
function savingsParts(f) {
  if (!f.counted_windows) return { none: true, value: NO_WINDOWS, interval: "", qualifier: "" };
  const ci = f.savings_ci95_pct;
  if (f.savings_pct === null || f.savings_pct === undefined) {
    return { none: false, value: "–", interval: "", qualifier: ci ? "" : noIntervalWords(f) };
  }
  if (!ci) return { none: false, value: pct(f.savings_pct), interval: "", qualifier: noIntervalWords(f) };
  const [low, high] = ci;
  return { none: false, value: pct(f.savings_pct), interval: `(95 % CI ${fmt(low, 1)} to ${fmt(high, 1)})`,
    qualifier: low <= 0 && high >= 0 ? "not yet distinguishable from zero" : "" };
}

/** "5.6 % (95 % CI 2.1 to 9.0)", "… — not yet distinguishable from zero", "4.1 % — confounded …". */
function savingsText(f) {
  const p = savingsParts(f);
  return [p.value, p.interval].filter(Boolean).join(" ") + (p.qualifier ? ` — ${p.qualifier}` : "");
}

/** A tile's value node for a savings figure: the value large, interval and qualifier smaller. */
function savingsValue(f) {
  const p = savingsParts(f);
  const node = el("div", { class: p.none ? "value none" : "value" }, el("span", { class: "main", text: p.value }));
  if (p.interval) node.append(" ", el("span", { class: "ci", text: p.interval }));
  if (p.qualifier) node.append(el("span", { class: "qualifier", text: ` — ${p.qualifier}` }));
  return node;
}

/** How a pair's savings are estimated, in words; `brief` where its savings say "confounded"
 *  already. */
function estimatorWords(f, brief = false) {
  const d = f.days || {};
  const lessThanADay = (f.savings_ci95_reason || "").startsWith("fewer than a day");
  if (f.estimator === "crossover") return `crossover over ${d.coach_0 + d.coach_1} days`;
  if (f.estimator === "fixed_reference") return `fixed plan, corrected by ${d.reference} reference day${d.reference === 1 ? "" : "s"}`;
  if (f.estimator === "fixed_naive" && lessThanADay) return brief ? "less than a day's windows" : "less than a day's windows: confounded with the coaches";
  if (f.estimator === "fixed_naive") return brief ? "fixed plan, no reference days" : "fixed plan: confounded with the coaches";
  return "no comparable days yet";
}

/** The days still needed for the interval's half-width to reach ±2 points, in words (`brief`:
 *  without "for ±2 points"). */
function daysToTargetWords(f, brief = false) {
  if (f.days_to_target === null || f.days_to_target === undefined) return "–";
  if (f.days_to_target === 0) return brief ? "reached" : "reached: ±2 points or better";
  return `about ${f.days_to_target} more day${f.days_to_target === 1 ? "" : "s"}${brief ? "" : " for ±2 points"}`;
}

/** How the fleet's figure is made: pooled over the trains with an interval, or the energy ratio. */
function fleetEstimatorWords(s) {
  const trains = (n) => `${n} train${n === 1 ? "" : "s"}`;
  if (!s.counted_windows) return "";
  const why = "confounded with the coaches (a fixed plan, or less than a day)";
  if (s.estimator === "random_effects") {
    return [`pooled over ${trains(s.trains_pooled)} with an interval (random effects)`,
      ...(s.trains_confounded ? [`${trains(s.trains_confounded)} left out: ${why}`] : []),
      `energy ratio of every train ${pct(s.naive_savings_pct)}`].join("; ");
  }
  return ["energy ratio over every train's counted windows",
    ...(s.trains_confounded ? [`${trains(s.trains_confounded)} ${why}`] : [])].join("; ");
}

/** The headline savings on their meter (the trial estimate with its interval), and the savings on
 *  the other meter (energy over energy). */
function savingsKpis(label, figures, id, sub = "") {
  const other = figures.meter === "hvac" ? "hvac_and_floor" : "hvac";
  const tile = kpi(`${label} (${METER_LABEL[figures.meter]})`, "", id);
  tile.classList.add("savings");
  tile.querySelector(".value").replaceWith(savingsValue(figures));
  if (sub) tile.append(el("div", { class: "sub", text: sub }));
  return [
    tile,
    kpi(`… ${METER_LABEL[other]}`, figures.counted_windows ? pct(figures.savings_by_meter_pct[other]) : "–", `${id}-other-meter`),
  ];
}

function drawFleetKpis(node, s, health) {
  const saved = s.energy_deactivated_kwh - s.energy_activated_kwh;
  const trains = s.trains.length;
  node.replaceChildren(
    ...savingsKpis("Fleet energy savings", s, "kpi-fleet-savings", fleetEstimatorWords(s)),
    kpi(`Energy saved (${METER_LABEL[s.meter]})`, `${fmt(saved, 0)} kWh`, "kpi-saved"),
    kpi("Avg hourly violation, activated", `${fmt(s.avg_hourly_violation_activated_k, 3)} K`, "kpi-violation"),
    kpi("… deactivated (reference)", `${fmt(s.avg_hourly_violation_deactivated_k, 3)} K`),
    kpi("Trains compared", `${trains}`, "kpi-trains"),
    kpi("Excluded", `${fmt(s.excluded_minutes / 60, 1)} train-hours`),
    kpi("Model, first-step error", health && health.mae_per_step_c.length && health.mae_per_step_c[0] !== null
      ? `${fmt(health.mae_per_step_c[0], 3)} K (bound ${fmt(health.bound_c, 2)} K)` : "–", "kpi-model"));
}

function drawModelFlag(node, health) {
  node.hidden = !(health && (health.exceeds_bound || health.drift));
  node.replaceChildren();
  if (node.hidden) return;
  const why = health.exceeds_bound
    ? `its online first-step error ${fmt(health.mae_per_step_c[0], 3)} K exceeds the ${fmt(health.bound_c, 2)} K bound`
    : `drift: ${health.drift_reason}`;
  node.append(`Model v${health.version}: ${why}. `, el("a", { href: "#/model", text: "Model health →" }));
}

function drawEnergy(node, s) {
  let act = 0, deact = 0;
  const x = s.windows.map((w) => local(new Date(new Date(w.start).getTime() + s.window_min * 60e3).toISOString()));
  const yAct = s.windows.map((w) => (act += w.energy_activated_kwh));
  const yDeact = s.windows.map((w) => (deact += w.energy_deactivated_kwh));
  const traces = [
    { x, y: yDeact, name: "deactivated coaches", line: { color: COLOUR.deact, shape: "hv" } },
    { x, y: yAct, name: "activated coaches", line: { color: COLOUR.act, shape: "hv" } },
  ];
  Plotly.react(node, traces, { margin: { t: 20, r: 20, l: 60, b: 50 }, hovermode: "x unified", legend: { orientation: "h", y: -0.2 },
    yaxis: { title: { text: "cumulative energy (kWh)" }, rangemode: "tozero" },
    xaxis: { title: { text: "local time (Europe/Zurich), windows counted for both coaches of a train" } } }, PLOT_CONFIG);
}

function drawTrainFigures(view, s) {
  const by = view.querySelector("#train-sort").value;
  const trains = [...s.trains].sort(by === "id" ? (a, b) => (a.id > b.id ? 1 : -1)
    : (a, b) => (b.savings_pct ?? -Infinity) - (a.savings_pct ?? -Infinity));
  const names = trains.map((t) => t.id);
  drawSavingsPerTrain(view, trains);
  Plotly.react(view.querySelector("#violation-figure"), [
    { type: "bar", x: names, y: trains.map((t) => t.avg_hourly_violation_activated_k), name: "activated", marker: { color: COLOUR.act } },
    { type: "bar", x: names, y: trains.map((t) => t.avg_hourly_violation_deactivated_k), name: "deactivated", marker: { color: COLOUR.deact } },
  ], { barmode: "group", margin: { t: 20, r: 20, l: 60, b: 50 }, legend: { orientation: "h", y: -0.2 },
    yaxis: { title: { text: "avg hourly violation (K)" }, rangemode: "tozero" }, xaxis: { type: "category" } }, PLOT_CONFIG);
}

/** One bar per train, its 95 % interval as error bars; a train without an interval hatched
 *  (confounded or too few days), one without a counted window marked so (no bar); and the same
 *  figures in words in the table below. A bar opens its train's pair comparison. */
function drawSavingsPerTrain(view, trains) {
  const names = trains.map((t) => t.id);
  const hover = trains.map((t) => `${t.name}: ${savingsText(t)}<br>${estimatorWords(t)}<br>` +
    `${fmt(t.energy_activated_kwh, 1)} / ${fmt(t.energy_deactivated_kwh, 1)} kWh, ${fmt(t.excluded_minutes, 0)} min excluded`);
  const shown = (t) => t.counted_windows > 0 && t.savings_pct !== null;
  const ci = (t) => shown(t) && t.savings_ci95_pct;
  const common = { type: "bar", x: names, hovertext: hover, customdata: names, hovertemplate: "%{x}: %{hovertext}<extra></extra>" };
  const savings = view.querySelector("#savings-figure");
  Plotly.react(savings, [
    { ...common, name: "with a 95 % interval (error bars)", y: trains.map((t) => (ci(t) ? t.savings_pct : null)),
      marker: { color: BAR.solid, line: { color: BAR.solid, width: 1.5 } },
      error_y: { type: "data", symmetric: false, color: BAR.whisker, thickness: 1.5, width: 6,
        array: trains.map((t) => (ci(t) ? t.savings_ci95_pct[1] - t.savings_pct : null)),
        arrayminus: trains.map((t) => (ci(t) ? t.savings_pct - t.savings_ci95_pct[0] : null)) } },
    { ...common, name: "no interval (confounded or too few days)", y: trains.map((t) => (shown(t) && !ci(t) ? t.savings_pct : null)),
      marker: { color: BAR.light, line: { color: BAR.solid, width: 1.5 }, pattern: { shape: "/", fgcolor: BAR.solid, bgcolor: BAR.light, size: 8, solidity: 0.25 } } },
  ], { barmode: "overlay", margin: { t: 20, r: 20, l: 60, b: 50 }, showlegend: true, legend: { orientation: "h", y: -0.25 },
    yaxis: { title: { text: "savings (%)" }, zeroline: true, zerolinecolor: "#5b6470" }, xaxis: { title: { text: "train" }, type: "category" },
    annotations: trains.filter((t) => !t.counted_windows).map((t) => ({ x: t.id, y: 0, yanchor: "bottom", text: "none<br>counted",
      showarrow: false, font: { size: 11, color: "#5b6470" } })) }, PLOT_CONFIG);
  savings.removeAllListeners?.("plotly_click");
  savings.on("plotly_click", (event) => { location.hash = `#/train/${encodeURIComponent(event.points[0].customdata)}`; });
  view.querySelector("#train-savings tbody").replaceChildren(...trains.map((t) => el("tr", { "data-train": t.id },
    el("td", {}, el("a", { href: `#/train/${encodeURIComponent(t.id)}`, text: t.id })),
    el("td", { class: "savings-text", text: savingsText(t) }),
    el("td", { text: t.counted_windows ? estimatorWords(t, true) : "–" }),
    el("td", { text: daysToTargetWords(t, true) }))));
}

function drawAttention(body, items) {
  body.replaceChildren(...(items.length ? items.map((a) => el("tr", { "data-coach": a.coach_id, "data-kind": a.kind },
    el("td", {}, el("a", { href: `#/coach/${encodeURIComponent(a.coach_id)}`, text: a.coach_id })),
    el("td", {}, el("span", { class: `badge ${a.kind === "comfort" ? "stale" : a.status}`, text: KIND_LABEL[a.kind] })),
    el("td", { text: a.detail })))
    : [el("tr", {}, el("td", { text: "nothing: every coach is fed, on its setpoint and within comfort" }))]));
}

// --- model health: the stored predictions against what happened ----------------------------
async function showModel() {
  const view = mount("tpl-model");
  view.querySelector("#model-hours").addEventListener("change", () => refresh().catch(report));
  async function refresh() {
    const h = await modelHealth(view.querySelector("#model-hours").value);
    if (!h) {
      view.querySelector("#model-kpis").textContent = "No model is active yet: the coaches follow the rule-based setpoint.";
      return;
    }
    view.querySelector("#model-title").textContent = `Model health: version ${h.version}`;
    view.querySelector("#model-kpis").replaceChildren(
      kpi("First-step MAE", h.mae_per_step_c[0] === undefined || h.mae_per_step_c[0] === null ? "–" : `${fmt(h.mae_per_step_c[0], 3)} K`, "kpi-first-step"),
      kpi("Bound", `${fmt(h.bound_c, 2)} K`),
      kpi("Within the bound", h.samples ? (h.exceeds_bound ? "no" : "yes") : "–", "kpi-within"),
      kpi("Samples", `${h.samples}`, "kpi-samples"),
      kpi("Prediction step", `${fmt(h.step_min, 0)} min`));
    const steps = h.mae_per_step_c.map((_, k) => (k + 1) * h.step_min);
    const models = await api("/models");
    const candidates = await Promise.all(models.filter((m) => m.state === "candidate")
      .map((m) => api(`/models/${m.version}/health?hours=${view.querySelector("#model-hours").value}`)));
    Plotly.react(view.querySelector("#mae-figure"), [
      { x: steps, y: h.mae_per_step_c, name: `active v${h.version}`, mode: "lines+markers", line: { color: COLOUR.act } },
      ...candidates.map((c) => ({ x: c.mae_per_step_c.map((_, k) => (k + 1) * c.step_min), y: c.mae_per_step_c,
        name: `candidate v${c.version} (shadow)`, mode: "lines+markers", line: { dash: "dot" } })),
      { x: steps.length ? [steps[0], steps[steps.length - 1]] : [], y: [h.bound_c, h.bound_c], name: `bound ${fmt(h.bound_c, 2)} K`, mode: "lines", line: { color: "#b42318", dash: "dash" } },
    ], { margin: { t: 20, r: 20, l: 60, b: 50 }, legend: { orientation: "h", y: -0.2 },
      xaxis: { title: { text: "prediction horizon (min)" } }, yaxis: { title: { text: "mean absolute error (K)" }, rangemode: "tozero" } }, PLOT_CONFIG);
    view.querySelector("#model-coaches tbody").replaceChildren(...(h.coaches.length ? h.coaches.map((c) => el("tr", { "data-coach": c.coach_id },
      el("td", {}, el("a", { href: `#/coach/${encodeURIComponent(c.coach_id)}`, text: c.coach_id })),
      el("td", { class: c.first_step_mae_c > h.bound_c ? "num expired" : "num", text: fmt(c.first_step_mae_c, 3) }),
      el("td", { class: "num", text: String(c.samples) }))) : [el("tr", {}, el("td", { text: "no prediction in the window yet" }))]));
    const mean = (v) => { const x = (v || []).filter((e) => e !== null); return x.length ? x.reduce((a, b) => a + b, 0) / x.length : null; };
    const beside = Object.fromEntries(candidates.map((c) => [c.version, c.beside]));
    view.querySelector("#model-versions tbody").replaceChildren(...models.map((m) => el("tr", { "data-version": String(m.version), "data-state": m.state },
      el("td", { text: `v${m.version}` }), el("td", {}, el("span", { class: `badge ${{ active: "active", candidate: "override", retired: "inactive" }[m.state]}`, text: m.state })),
      el("td", { class: "num", text: fmt(mean(m.validation_mae_per_step_c), 3) }),
      el("td", { class: "num", text: fmt(mean(m.online_mae_per_step_c), 3) }),
      el("td", { class: "num", text: beside[m.version] ? fmt(mean(beside[m.version].mae_per_step_c), 3) : "–" }))));
  }
  await every(2 * REFRESH_MS, refresh);
}

// --- fleet overview ------------------------------------------------------------------------
async function showFleet() {
  const view = mount("tpl-fleet");
  const body = view.querySelector("#coaches tbody");
  let coaches = [];
  const draw = () => {
    const text = view.querySelector("#filter").value.toLowerCase();
    const status = view.querySelector("#status-filter").value;
    const { key, dir } = state.sort;
    const by = (c) => sortValue(c, key);
    const rows = coaches
      .filter((c) => !status || c.status === status)
      .filter((c) => !text || [c.id, c.train_id, c.status, c.reason || ""].some((s) => s.toLowerCase().includes(text)))
      .sort((a, b) => (by(a) > by(b) ? dir : by(a) < by(b) ? -dir : 0));
    body.replaceChildren(...rows.map((c) => {
      const temps = c.t_room_c ? c.t_room_c.map((t) => fmt(t)).join(" / ") : "–";
      const band = c.t_rule_c === null ? "–" : `${fmt(c.t_rule_c - c.comfort_band_k)} – ${fmt(c.t_rule_c + c.comfort_band_k)}`;
      return el("tr", { "data-coach": c.id },
        el("td", {}, el("a", { href: `#/coach/${encodeURIComponent(c.id)}`, text: c.id })),
        el("td", { text: c.train_id }),
        el("td", { text: c.ddpc_active ? "activated" : "deactivated" }),
        el("td", {}, badge(c)),
        el("td", { text: c.mode || "–" }),
        el("td", { class: "num", text: temps }),
        el("td", { class: "comfort" }, comfortBadge(c)),
        el("td", { class: "num" }, tRefCell(c)),
        el("td", { class: "num", text: band }),
        el("td", { class: "num", text: fmt(c.last_solve_ms, 3) }),
        el("td", {}, el("a", { href: `#/train/${encodeURIComponent(c.train_id)}`, text: "compare" })));
    }));
    view.querySelectorAll("th[data-sort]").forEach((th) => {
      th.classList.toggle("sorted-asc", th.dataset.sort === key && dir === 1);
      th.classList.toggle("sorted-desc", th.dataset.sort === key && dir === -1);
    });
  };
  view.querySelector("#filter").addEventListener("input", draw);
  view.querySelector("#status-filter").addEventListener("change", draw);
  view.querySelectorAll("th[data-sort]").forEach((th) => th.addEventListener("click", () => {
    state.sort = { key: th.dataset.sort, dir: state.sort.key === th.dataset.sort ? -state.sort.dir : 1 };
    draw();
  }));
  await every(REFRESH_MS, async () => {
    const [list, replicas] = await Promise.all([api("/coaches"), api("/replicas")]);
    coaches = list;
    const clock = coaches.map((c) => c.clock).filter(Boolean).sort().pop();
    view.querySelector("#fleet-clock").textContent = clock ? `fleet clock ${local(clock)} (Zurich)` : "";
    drawFeedDown(view.querySelector("#feed-down"), coaches);
    draw();
    drawReplicas(view.querySelector("#replicas tbody"), replicas);
  });
}

/** The value the coaches list sorts column ``key`` by: comfort by how far outside the band
 *  (unknown before any within it). */
function sortValue(coach, key) {
  if (key === "comfort") return coach.comfort ? coach.comfort.worst_excess_k : -1;
  return coach[key];
}

/** "Feed down since …" when there are live coaches and nothing arrives from any of them. */
function drawFeedDown(node, coaches) {
  const live = coaches.filter((c) => c.fleet === "live");
  const seen = live.map((c) => c.last_seen_at).filter(Boolean).sort();
  const down = live.length > 0 && seen.length > 0 && live.every((c) => c.status === "stale" || !c.last_seen_at);
  node.hidden = !down;
  node.textContent = down
    ? `Live feed down since ${local(seen[seen.length - 1])} (Zurich): no telemetry arrives from any gateway. ` +
      "The coaches' HVACs follow their own T_rule once their last setpoint expires."
    : "";
}

/** The replicas that decided ticks in the last hour: which coaches each took, how many ticks. */
function drawReplicas(body, replicas) {
  body.replaceChildren(...replicas.map((r) => el("tr", { "data-replica": r.replica },
    el("td", { text: r.this ? `${r.replica} (this one)` : r.replica }),
    el("td", { text: `${r.coaches.length}: ${r.coaches.join(", ")}` }),
    el("td", { class: "num", text: String(r.ticks) }),
    el("td", { text: local(r.last_seen) }))));
  if (!replicas.length) body.append(el("tr", {}, el("td", { colspan: "4", text: "no ticks decided in the last hour" })));
}

// --- the pair's trial figures: which coach ran the layer in each window, what was excluded ----
/** Consecutive windows alike in `key(w)` as runs {key, start, end} (ms since 1970; a gap in the
 *  windows ends a run). */
function windowRuns(windows, windowMin, key) {
  const out = [];
  for (const w of windows) {
    const start = new Date(w.start).getTime();
    const end = start + windowMin * 60e3;
    const k = key(w);
    const last = out[out.length - 1];
    if (last && last.key === k && last.end === start) last.end = end;
    else out.push({ key: k, start, end });
  }
  return out.filter((r) => r.key !== null);
}

/** The strip above the pair's chart: its two rows (which coach ran the layer; the windows
 *  excluded from the savings), each this tall, and the gap between them. [px] */
const STRIP_PX = { row: 15, gap: 2 };

/** The pair chart's shading: per run of windows, the coach under the layer as a strip above the
 *  chart (labelled where wide enough) and a light shade down the chart; excluded windows red in
 *  a second row of the strip (their reason written in it) and lightly shaded. Adds to `layout`
 *  (the top panel moves down to make room), for a chart of `width` × `height` px. */
function shadeWindows(layout, cmp, width, height) {
  const colour = (key) => (key === "neither" ? NEITHER_SHADE : COACH_SHADE[cmp.coaches.indexOf(key)] || NEITHER_SHADE);
  const layer = windowRuns(cmp.windows, cmp.window_min, (w) => w.activated ?? (w.excluded_reason === "reference" ? "neither" : null));
  const excluded = windowRuns(cmp.windows, cmp.window_min, (w) => (w.excluded && w.excluded_reason !== "reference" ? w.excluded_reason : null));
  const span = cmp.windows.length ? cmp.windows.length * cmp.window_min * 60e3 : 1;
  const px = Math.max(200, width - (layout.margin.l + layout.margin.r));
  const py = Math.max(300, height - (layout.margin.t + layout.margin.b));
  const row = STRIP_PX.row / py;
  const gap = STRIP_PX.gap / py;
  const rows = { layer: [1 - row, 1], excluded: [1 - 2 * row - gap, 1 - row - gap] };
  const top = 1 - 2 * row - 4 * gap;
  const iso = (ms) => local(new Date(ms).toISOString());
  // a run's label: the longest of its texts that fits (about 6.5 px a character at 11 px)
  const label = (run, texts) => {
    const text = texts.find((t) => t.length * 6.5 + 8 <= ((run.end - run.start) / span) * px);
    return text ? { text, font: { color: "#ffffff", size: 11 }, textposition: "middle center" } : undefined;
  };
  const strip = (run, name, fill, texts) => ({ type: "rect", name: `${name}:${run.key}`, xref: "x", yref: "paper",
    x0: iso(run.start), x1: iso(run.end), y0: rows[name][0], y1: rows[name][1], fillcolor: fill, line: { color: "#ffffff", width: 1 },
    layer: "above", label: label(run, texts) });
  const shade = (run, name, fill, opacity) => ({ type: "rect", name: `shade-${name}:${run.key}`, xref: "x", yref: "paper",
    x0: iso(run.start), x1: iso(run.end), y0: 0, y1: top, fillcolor: fill, opacity, line: { width: 0 }, layer: "below" });
  layout.shapes = [...(layout.shapes || []),
    ...layer.map((r) => shade(r, "layer", colour(r.key), 0.07)),
    ...excluded.map((r) => shade(r, "excluded", EXCLUDED_SHADE, 0.1)),
    ...layer.map((r) => strip(r, "layer", colour(r.key), r.key === "neither" ? ["reference: both on T_rule", "reference", "ref"] : [`${r.key} under the layer`, r.key])),
    ...excluded.map((r) => strip(r, "excluded", EXCLUDED_SHADE, [EXCLUDED_REASON[r.key] || r.key, r.key]))];
  // the rows named at the right, where the top panels have no axis
  const side = ([y0, y1], text) => ({ xref: "paper", yref: "paper", x: 1, xanchor: "left", xshift: 4, y: (y0 + y1) / 2, yanchor: "middle",
    text, showarrow: false, font: { size: 11, color: "#5b6470" } });
  layout.annotations = [...(layout.annotations || []), side(rows.layer, "layer"), side(rows.excluded, "excluded")];
  layout.yaxis.domain = [layout.yaxis.domain[0], Math.min(layout.yaxis.domain[1], top)];
}

/** The key to the strip above the pair's chart, in words with colour swatches. */
function drawPairKey(node, cmp) {
  const item = (cls, text) => el("span", { class: "key-item" }, el("span", { class: `swatch ${cls}`, "aria-hidden": "true" }), text);
  const [c0, c1] = cmp.coaches;
  node.replaceChildren(el("span", { class: "key-title", text: `Strip above the chart, per ${fmt(cmp.window_min, 0)}-min window:` }), " ",
    item("coach-0", `${c0} under the layer (${c1} on T_rule)`),
    item("coach-1", `${c1} under the layer (${c0} on T_rule)`),
    item("neither", "reference: both on T_rule"),
    item("excluded", "excluded from the savings (the reason in the strip where it fits, and in the table)"),
    el("span", { class: "hint", text: "The same runs are shaded lightly down the chart." }));
}

/** The excluded minutes by reason (most first), the reference windows beside them, and the sum. */
function drawExcludedReasons(body, cmp) {
  const rows = Object.entries(cmp.excluded_minutes_by_reason || {}).sort((a, b) => b[1] - a[1]);
  const reference = cmp.windows.filter((w) => w.excluded_reason === "reference").length * cmp.window_min;
  if (reference) rows.push(["reference", reference]);
  const row = (reason, minutes) => el("tr", { "data-reason": reason },
    el("td", { text: EXCLUDED_REASON[reason] || reason }), el("td", { class: "num", text: fmt(minutes, 0) }));
  body.replaceChildren(...(rows.length ? rows.map(([r, m]) => row(r, m)) : [el("tr", {}, el("td", { colspan: "2", text: "none: every window counts" }))]));
  if (rows.length) body.append(el("tr", { class: "total" }, el("td", { text: "excluded in all" }), el("td", { class: "num", text: fmt(cmp.excluded_minutes, 0) })));
}

/** A tile whose value is words, not a figure (set smaller). */
function wordy(tile) {
  tile.classList.add("wordy");
  return tile;
}

/** The pair's savings tiles: the estimate with its interval, how it is made, the days to ±2
 *  points, Guideline 14, and the energy ratio with the coaches' difference in it. */
function pairSavingsKpis(cmp) {
  const counted = cmp.counted_windows > 0;
  const g14 = cmp.meets_guideline_14 === null || cmp.meets_guideline_14 === undefined ? "–" : cmp.meets_guideline_14 ? "yes" : "no";
  return [
    ...savingsKpis("Energy savings", cmp, "kpi-savings"),
    wordy(kpi("Estimate", counted ? estimatorWords(cmp) : "–", "kpi-estimator")),
    wordy(kpi("Days to ±2 points", daysToTargetWords(cmp), "kpi-days-to-target")),
    kpi("ASHRAE Guideline 14 met", g14, "kpi-guideline-14"),
    kpi("Energy ratio, coaches' difference included", counted ? pct(cmp.naive_savings_pct) : "–", "kpi-naive"),
  ];
}

// --- pair comparison (the paper's experiment figure, live) ---------------------------------
function rangeQuery(view, clock) {
  const choice = view.querySelector("#range").value;
  if (choice === "custom") {
    const start = view.querySelector("#range-start").value;
    const end = view.querySelector("#range-end").value;
    if (start && end) return `?start=${encodeURIComponent(zurichToIso(start))}&end=${encodeURIComponent(zurichToIso(end))}`;
  }
  const hours = choice === "custom" ? 24 : Number(choice);
  if (!clock) return "";
  const end = new Date(clock);
  const start = new Date(end.getTime() - hours * 3600e3);
  return `?start=${encodeURIComponent(start.toISOString())}&end=${encodeURIComponent(end.toISOString())}`;
}

/** "YYYY-MM-DDTHH:MM" in Zurich time → ISO UTC (finding the offset that round-trips). */
function zurichToIso(value) {
  const guess = new Date(`${value}:00Z`);
  for (const offsetH of [1, 2, 0]) {
    const candidate = new Date(guess.getTime() - offsetH * 3600e3);
    if (local(candidate.toISOString()).startsWith(value.replace("T", " "))) return candidate.toISOString();
  }
  return guess.toISOString();
}

async function showTrain(trainId) {
  const view = mount("tpl-train");
  const train = await api(`/trains/${encodeURIComponent(trainId)}`);
  view.querySelector("#train-title").textContent = `Train ${train.id}: ${train.name}`;
  const rangeSelect = view.querySelector("#range");
  rangeSelect.addEventListener("change", () => {
    view.querySelector("#custom-range").hidden = rangeSelect.value !== "custom";
    if (rangeSelect.value !== "custom") refresh().catch(report);
  });
  view.querySelector("#range-apply").addEventListener("click", () => refresh().catch(report));
  const drawPlan = planControl(view, trainId);
  if (!train.activated.length || !train.deactivated.length) {
    view.querySelector("#summary").textContent = "This train has no pair of an activated and a deactivated coach.";
    return every(2 * REFRESH_MS, drawPlan);
  }
  const [act, deact] = [train.activated[0], train.deactivated[0]];
  async function refresh() {
    drawPlan().catch(report);
    const coach = await api(`/coaches/${encodeURIComponent(act)}`);
    const q = rangeQuery(view, coach.clock);
    const [cmp, a, b] = await Promise.all([
      api(`/trains/${encodeURIComponent(trainId)}/comparison${q}`),
      api(`/coaches/${encodeURIComponent(act)}/timeseries${q}`),
      api(`/coaches/${encodeURIComponent(deact)}/timeseries${q}`),
    ]);
    view.querySelector("#train-clock").textContent = coach.clock ? `clock ${local(coach.clock)} (Zurich)` : "";
    view.querySelector("#summary").replaceChildren(
      ...pairSavingsKpis(cmp),
      kpi(`Avg hourly violation, activated ${act}`, `${fmt(cmp.avg_hourly_violation_k, 3)} K`),
      kpi(`Avg hourly violation, deactivated ${deact}`, `${fmt(cmp.baseline_violation_k, 3)} K`),
      kpi(`Energy activated / deactivated (${METER_LABEL[cmp.meter]})`, `${fmt(cmp.energy_activated_kwh, 1)} / ${fmt(cmp.energy_deactivated_kwh, 1)} kWh`),
      kpi("Excluded", `${fmt(cmp.excluded_minutes, 0)} min`));
    drawPairKey(view.querySelector("#pair-key"), cmp);
    drawExcludedReasons(view.querySelector("#excluded-reasons tbody"), cmp);
    drawPair(view.querySelector("#pair-figure"), cmp, a, b, act, deact, coach.comfort_band_k);
  }
  await every(2 * REFRESH_MS, refresh);
}

/** The pair view's trial plan: the one in force and a pending change with its effective time;
 *  operators change it (PUT, from the next switch hour). Returns the function that redraws it. */
function planControl(view, trainId) {
  const url = `/trains/${encodeURIComponent(trainId)}/plan`;
  const form = view.querySelector("#plan-form");
  const error = view.querySelector("#plan-error");
  let chosen = false; // the form starts on the plan in force, then keeps what the operator picks
  async function draw() {
    const p = await api(url);
    const today = p.activated_today ? `${p.activated_today} runs the layer today` : "neither coach runs the layer today";
    // a plan set before the train had any clock is in force from its first moment (1970)
    const since = p.effective_from && p.effective_from >= "2000" ? ` since ${local(p.effective_from).slice(0, 16)}` : "";
    const state = view.querySelector("#plan-state");
    state.dataset.plan = p.plan;
    state.textContent = `In force: ${p.plan}${since}, switch hour ${p.switch_hour}:00 (Zurich); ${today}.`;
    const pending = view.querySelector("#plan-pending");
    pending.dataset.plan = p.pending ? p.pending.plan : "";
    pending.textContent = p.pending
      ? `Pending: ${p.pending.plan} from ${local(p.pending.effective_from).slice(0, 16)} (Zurich), set by ${p.pending.created_by}: ${p.pending.reason}`
      : `No change pending; the next service day starts at ${local(p.next_switch).slice(0, 16)} (Zurich).`;
    if (!chosen) {
      view.querySelector("#plan-select").value = p.plan;
      view.querySelector("#plan-hour").value = String(p.switch_hour);
    }
  }
  form.addEventListener("input", () => { chosen = true; });
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    error.textContent = "";
    try {
      const p = await api(url, { method: "PUT", body: JSON.stringify({
        plan: view.querySelector("#plan-select").value,
        switch_hour: Number(view.querySelector("#plan-hour").value),
        reason: view.querySelector("#plan-reason").value }) });
      view.querySelector("#plan-message").textContent = p.message;
      view.querySelector("#plan-reason").value = "";
      await draw();
    } catch (err) {
      error.textContent = err.message;
    }
  });
  return draw;
}

function temperatureTraces(ts, axis, showlegend, band) {
  const t = ts.time.map(local);
  const traces = [];
  for (const [offset, name] of [[band, "upper bound"], [-band, "lower bound"]]) {
    traces.push({ x: t, y: ts.t_rule_c.map((r) => (r === null ? null : r + offset)), name, legendgroup: name, showlegend, yaxis: axis,
      line: { color: COLOUR.band, dash: "dot", width: 1 } });
  }
  DECKS.forEach((deck, d) => traces.push({ x: t, y: ts.t_room_c.map((r) => r[d]), name: `T_room ${deck}`, legendgroup: deck, showlegend, yaxis: axis,
    line: { color: DECK_COLOUR[deck], width: 1.3 } }));
  traces.push({ x: t, y: ts.t_ref_c, name: "T_ref", legendgroup: "ref", showlegend, yaxis: axis, line: { color: COLOUR.ref, dash: "dash", width: 1.6 } });
  return traces;
}

/** Cumulative energy (kWh) of 1-min rows on ``meter``: the HVAC units' leave the floor heating out. */
function cumulative(ts, meter) {
  let sum = 0;
  return ts.power_kw.map((p, i) => (sum += ((p || 0) - (meter === "hvac" ? ts.floor_power_kw[i] || 0 : 0)) / 60));
}

function drawPair(node, cmp, a, b, act, deact, band) {
  const traces = [
    ...temperatureTraces(b, "y", true, band),
    ...temperatureTraces(a, "y2", false, band),
    { x: a.time.map(local), y: a.t_amb_c, name: "T_amb", yaxis: "y3", line: { color: COLOUR.amb } },
    { x: a.time.map(local), y: a.ghi_w_m2, name: "global irradiance", yaxis: "y4", line: { color: COLOUR.ghi } },
    { x: b.time.map(local), y: cumulative(b, cmp.meter), name: `energy ${deact} (deactivated)`, yaxis: "y5", line: { color: COLOUR.deact } },
    { x: a.time.map(local), y: cumulative(a, cmp.meter), name: `energy ${act} (activated)`, yaxis: "y5", line: { color: COLOUR.act } },
    { type: "bar", x: cmp.windows.map((w) => local(new Date(new Date(w.start).getTime() + cmp.window_min * 30e3).toISOString())),
      y: cmp.windows.map((w) => w.savings_pct), name: "30-min savings (%)", yaxis: "y6",
      marker: { color: "rgba(0, 114, 178, 0.55)", line: { color: BAR.solid, width: 1 } }, width: cmp.window_min * 60e3 * 0.8 },
  ];
  const layout = {
    margin: { t: 30, r: 70, l: 70, b: 50 }, hovermode: "x unified", legend: { orientation: "h", y: -0.08 },
    xaxis: { title: { text: "local time (Europe/Zurich)" }, anchor: "y5" },
    yaxis: { title: { text: `${deact} deactivated (°C)` }, domain: [0.76, 1], anchor: "x" },
    yaxis2: { title: { text: `${act} activated (°C)` }, domain: [0.51, 0.73], anchor: "x" },
    yaxis3: { title: { text: "T_amb (°C)" }, domain: [0.27, 0.48], anchor: "x" },
    yaxis4: { title: { text: "irradiance (W/m²)" }, overlaying: "y3", side: "right", anchor: "x", rangemode: "tozero", tickmode: "auto" },
    yaxis5: { title: { text: `energy, ${METER_LABEL[cmp.meter]} (kWh)` }, domain: [0, 0.24], anchor: "x" },
    yaxis6: { title: { text: "30-min savings (%)" }, overlaying: "y5", side: "right", anchor: "x", showgrid: false, rangemode: "tozero", tickmode: "auto" },
  };
  shadeWindows(layout, cmp, node.clientWidth, node.clientHeight);
  Plotly.react(node, traces, layout, { responsive: true, displaylogo: false });
}

// --- coach detail --------------------------------------------------------------------------
async function showCoach(coachId) {
  const view = mount("tpl-coach");
  view.querySelector("#coach-title").textContent = `Coach ${coachId}`;
  const form = view.querySelector("#override-form");
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const error = view.querySelector("#ov-error");
    error.textContent = "";
    try {
      await api(`/coaches/${encodeURIComponent(coachId)}/override`, { method: "POST", body: JSON.stringify({
        t_ref_c: Number(view.querySelector("#ov-value").value),
        duration_min: Number(view.querySelector("#ov-duration").value),
        reason: view.querySelector("#ov-reason").value }) });
      form.reset();
      await refresh();
    } catch (err) {
      error.textContent = err.message;
    }
  });
  view.querySelector("#layer-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const coach = await api(`/coaches/${encodeURIComponent(coachId)}`);
    await api(`/coaches/${encodeURIComponent(coachId)}/controller`, { method: "PUT", body: JSON.stringify({
      active: !coach.ddpc_active, reason: view.querySelector("#layer-reason").value }) });
    view.querySelector("#layer-form").reset();
    await refresh();
  });

  async function refresh() {
    const coach = await api(`/coaches/${encodeURIComponent(coachId)}`);
    const [ts, sp, overrides, audit] = await Promise.all([
      api(`/coaches/${encodeURIComponent(coachId)}/timeseries`),
      api(`/coaches/${encodeURIComponent(coachId)}/setpoints`),
      api(`/coaches/${encodeURIComponent(coachId)}/overrides`),
      api(`/audit?target=${encodeURIComponent(coachId)}&limit=50`),
    ]);
    view.querySelector("#coach-clock").textContent = coach.clock ? `clock ${local(coach.clock)} (Zurich)` : "";
    view.querySelector("#coach-status").replaceChildren(
      kpi("Status", "", "kpi-status"),
      kpi("Layer", coach.ddpc_active ? "activated" : "deactivated"),
      kpi(coach.t_ref_applied === false ? "T_ref issued, not applied: the HVAC holds T_rule" : "T_ref", `${fmt(coach.t_ref_c, 2)} °C`, "kpi-t-ref"),
      kpi("T_rule band", coach.t_rule_c === null ? "–" : `${fmt(coach.t_rule_c - coach.comfort_band_k)} – ${fmt(coach.t_rule_c + coach.comfort_band_k)} °C`),
      kpi("Comfort now", "", "kpi-comfort"),
      kpi("Last solve", `${fmt(coach.last_solve_ms, 3)} ms`));
    view.querySelector("#kpi-status .value").replaceChildren(badge(coach));
    view.querySelector("#kpi-comfort .value").replaceChildren(comfortBadge(coach));
    view.querySelector("#layer-button").textContent = coach.ddpc_active ? "Switch the layer off" : "Switch the layer on";
    view.querySelector("#ov-band").textContent = coach.t_rule_c === null ? "" :
      `Allowed: ${fmt(coach.t_rule_c - coach.setpoint_band_k)} – ${fmt(coach.t_rule_c + coach.setpoint_band_k)} °C (T_rule ± ${fmt(coach.setpoint_band_k, 0)} K, the driver's limit).`;
    drawPrediction(view.querySelector("#prediction-figure"), ts, sp);
    drawSources(view.querySelector("#sources-figure"), sp);
    view.querySelector("#overrides tbody").replaceChildren(...(overrides.length ? overrides.map((o) => el("tr", {},
      el("td", { text: `${fmt(o.t_ref_c, 1)} °C` }),
      el("td", { text: `${local(o.starts_at).slice(11, 16)}–${local(o.ends_at).slice(11, 16)}` }),
      el("td", { text: `${o.created_by}: ${o.reason}` }),
      el("td", {}, o.active && state.me.role !== "viewer" ? cancelButton(coachId, refresh) : el("span", { text: o.active ? "active" : "ended" }))))
      : [el("tr", {}, el("td", { text: "none" }))]));
    view.querySelector("#coach-audit tbody").replaceChildren(...(audit.length ? audit.map((a) => el("tr", {},
      el("td", { text: local(a.time) }), el("td", { text: a.user }), el("td", { text: a.action }), el("td", { text: a.reason }))) :
      [el("tr", {}, el("td", { text: "nothing yet" }))]));
  }
  await every(REFRESH_MS, refresh);
}

function cancelButton(coachId, after) {
  const button = el("button", { class: "secondary", text: "Cancel" });
  button.addEventListener("click", async () => {
    await api(`/coaches/${encodeURIComponent(coachId)}/override?reason=${encodeURIComponent("cancelled on the dashboard")}`, { method: "DELETE" });
    await after();
  });
  return button;
}

function drawPrediction(node, ts, sp) {
  const times = ts.time.map((t) => new Date(t).getTime());
  const last = times.length ? times[times.length - 1] : 0;
  // the newest prediction whose horizon has passed, so it can be compared with what happened
  let index = -1;
  for (let i = sp.tick.length - 1; i >= 0; i--) {
    const p = sp.predicted[i];
    if (p && p.y_pred_c && new Date(sp.tick[i]).getTime() + p.y_pred_c.length * 300e3 <= last) { index = i; break; }
  }
  if (index < 0) {
    Plotly.react(node, [], { annotations: [{ text: "no completed prediction yet (the layer warms up for an hour)", showarrow: false, xref: "paper", yref: "paper", x: 0.5, y: 0.5 }],
      xaxis: { visible: false }, yaxis: { visible: false } }, { responsive: true, displaylogo: false });
    return;
  }
  const tick = new Date(sp.tick[index]).getTime();
  const pred = sp.predicted[index];
  const steps = pred.y_pred_c.map((_, k) => local(new Date(tick + (k + 1) * 300e3).toISOString()));
  const start = tick - 3600e3;
  const end = tick + pred.y_pred_c.length * 300e3;
  const sel = times.map((t, i) => (t >= start && t <= end ? i : -1)).filter((i) => i >= 0);
  const traces = [];
  DECKS.forEach((deck, d) => {
    traces.push({ x: sel.map((i) => local(ts.time[i])), y: sel.map((i) => ts.t_room_c[i][d]), name: `measured ${deck}`, line: { color: DECK_COLOUR[deck], width: 1.2 } });
    traces.push({ x: steps, y: pred.y_pred_c.map((row) => row[d]), name: `predicted ${deck}`, mode: "lines+markers", line: { color: DECK_COLOUR[deck], dash: "dash" } });
  });
  traces.push({ x: [local(sp.tick[index]), ...steps], y: pred.t_opt_c, name: "T_opt", line: { color: COLOUR.band, dash: "dot" } });
  traces.push({ x: [local(sp.tick[index]), ...steps], y: pred.u_plan_c, name: "planned T_ref", line: { color: COLOUR.ref, dash: "dash", shape: "hv" } });
  Plotly.react(node, traces, { margin: { t: 20, r: 20, l: 60, b: 50 }, yaxis: { title: { text: "°C" } },
    xaxis: { title: { text: `local time (Europe/Zurich), prediction made at ${local(sp.tick[index]).slice(11, 16)}` } },
    shapes: [{ type: "line", xref: "x", yref: "paper", x0: local(sp.tick[index]), x1: local(sp.tick[index]), y0: 0, y1: 1, line: { dash: "dot", color: "#444" } }] },
  { responsive: true, displaylogo: false });
}

function drawSources(node, sp) {
  const traces = Object.keys(SOURCE_COLOUR).map((source) => {
    const idx = sp.source.map((s, i) => (s === source ? i : -1)).filter((i) => i >= 0);
    return { x: idx.map((i) => local(sp.tick[i])), y: idx.map((i) => sp.t_ref_c[i]), name: source, mode: "markers",
      marker: { color: SOURCE_COLOUR[source], size: 6 }, text: idx.map((i) => sp.reason[i]), hovertemplate: "%{x}<br>%{y:.2f} °C<br>%{text}" };
  });
  traces.push({ x: sp.tick.map(local), y: sp.t_rule_c, name: "T_rule", line: { color: COLOUR.band, dash: "dot" } });
  Plotly.react(node, traces, { margin: { t: 20, r: 20, l: 60, b: 50 }, yaxis: { title: { text: "T_ref issued (°C)" } },
    xaxis: { title: { text: "local time (Europe/Zurich)" } } }, { responsive: true, displaylogo: false });
}

// --- audit log -----------------------------------------------------------------------------
async function showAudit() {
  const view = mount("tpl-audit");
  await every(REFRESH_MS, async () => {
    const rows = await api("/audit?limit=200");
    view.querySelector("#audit tbody").replaceChildren(...rows.map((a) => el("tr", {},
      el("td", { text: local(a.time) }), el("td", { text: a.user }), el("td", { text: a.role }), el("td", { text: a.action }),
      el("td", { text: a.target }), el("td", { text: a.reason }), el("td", { text: JSON.stringify(a.detail) }))));
  });
}

// --- API tokens (admins only) ---------------------------------------------------------------
/** Who revoked a token, by token id, from the audit log (`token.revoke`, target `token:ID`);
 *  looked up once per revoked token (a revocation is final); null if the log has no entry. */
const revokers = new Map();

async function showTokens() {
  const view = mount("tpl-tokens");
  const error = view.querySelector("#tokens-error");

  async function load() {
    try {
      const tokens = await api("/tokens");
      await findRevokers(tokens);
      drawTokens(view, tokens, revoke);
    } catch (err) {
      error.textContent = `Loading the tokens failed: ${err.message}`;
    }
  }

  async function revoke(token) {
    const question = `Revoke the ${token.role} token ${token.prefix}… of ${token.user}? ` +
      "It stops working at once (every request with it gets 401); this cannot be undone.";
    if (!window.confirm(question)) return;
    error.textContent = "";
    try {
      await api(`/tokens/${token.id}`, { method: "DELETE" });
    } catch (err) {
      error.textContent = `Revoking ${token.prefix}… of ${token.user} failed: ${err.message}`;
      return;
    }
    await load();
  }

  view.querySelector("#tokens-refresh").addEventListener("click", () => {
    error.textContent = "";
    load();
  });
  await load();
}

async function findRevokers(tokens) {
  const unknown = tokens.filter((t) => t.revoked_at && !revokers.has(t.id));
  await Promise.all(unknown.map(async (t) => {
    const [entry] = await api(`/audit?target=${encodeURIComponent(`token:${t.id}`)}&limit=1`);
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
  return token.user === state.me.name && state.token.startsWith(token.prefix);
}

function drawTokens(view, tokens, revoke) {
  const now = Date.now();
  const minute = (iso) => local(iso).slice(0, 16);
  view.querySelector("#tokens tbody").replaceChildren(...(tokens.length ? tokens.map((t) => {
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
      el("td", {}, el("span", { class: `badge ${status}`, text: status })),
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

// --- start ---------------------------------------------------------------------------------
document.getElementById("signin-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  try {
    await signIn(document.getElementById("token").value.trim());
    document.getElementById("signin").close();
    route();
  } catch (err) {
    showSignIn(err.message);
  }
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

(async () => {
  state.token = tokenFromFragment() || state.token;
  if (!state.token) return showSignIn();
  try {
    await signIn(state.token);
    route();
  } catch {
    showSignIn("Your session has ended; sign in again.");
  }
})();
