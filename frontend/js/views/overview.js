// The fleet overview: savings, comfort and what needs attention. The summary and the coaches
// every 30 s, the model's health every minute; the per-train figures as CSV.
import { download } from "../api.js";
import { BAR, COLOUR, DASH, plot } from "../charts.js";
import { FLEET, METER_LABEL, el, fmt, kpi, local, naturalCompare, statusBadge, sync } from "../format.js";
import { daysToTargetWords, estimatorWords, fleetEstimatorWords, savingsKpis, savingsText } from "../savings.js";

/** How often the overview asks for the summary and the coaches, and for the model's health. [ms] */
export const SUMMARY_MS = 30_000;
export const MODEL_MS = 60_000;
const KIND_LABEL = { stale: "stale", disconnected: "disconnected", fallback: "fallback", override: "override", comfort: "comfort", costing_energy: "costs energy" };

/** The active model's health, or null while there is none (the first start prepares it). */
export async function modelHealth(view, hours) {
  const active = (await view.api("/models")).find((m) => m.active);
  return active ? view.api(`/models/${active.version}/health?hours=${hours}`) : null;
}

export async function mount(view) {
  let summary = null;
  let health = null;
  const hours = () => view.$("#hours").value;
  const drawTrains = () => summary && drawTrainFigures(view, summary);
  const drawKpis = () => summary && drawFleetKpis(view.$("#fleet-kpis"), summary, health);
  view.$("#train-sort").addEventListener("change", drawTrains);
  view.$("#hours").addEventListener("change", () => Promise.all([view.refresh(refresh), view.refresh(refreshModel)]));
  view.$("#overview-export").addEventListener("click", () => exportCsv(view, `/fleet/summary.csv?hours=${hours()}`));
  async function refreshModel() {
    health = await modelHealth(view, hours());
    if (view.left) return;
    drawModelFlag(view.$("#model-flag"), health);
    drawKpis();
  }
  async function refresh() {
    const [s, coaches] = await Promise.all([view.api(`/fleet/summary?hours=${hours()}`), view.api("/coaches")]);
    if (view.left) return;
    summary = s;
    drawFeedDown(view.$("#feed-down"), coaches);
    const end = s.trains.map((t) => t.end).sort().pop();
    view.$("#overview-clock").textContent = end ? `${local(end)} (${FLEET})` : "";
    drawKpis();
    drawEnergy(view.$("#energy-figure"), s);
    drawTrains();
    drawAttention(view.$("#attention tbody"), s.attention);
    sync(view.$("#by-status"), Object.entries(s.coaches_by_status).map(([status, n]) =>
      el("a", { href: "#/coaches", class: "status-count", "data-status": status }, statusBadge(status, status), el("span", { text: ` ${n}` }))));
  }
  view.every(MODEL_MS, refreshModel);
  await view.every(SUMMARY_MS, refresh);
}

/** Downloads a CSV, saying so (or why it failed) in the view's export status. */
export async function exportCsv(view, path) {
  const status = view.$(".export-status");
  status.textContent = "Preparing the CSV…";
  try {
    const name = await download(path, { signal: view.signal });
    status.textContent = `Downloaded ${name}.`;
  } catch (err) {
    if (!view.left) status.textContent = `The export failed: ${err.message}`;
  }
}

function drawFleetKpis(node, s, health) {
  const saved = s.energy_deactivated_kwh - s.energy_activated_kwh;
  sync(node, [
    ...savingsKpis("Fleet energy savings", s, "kpi-fleet-savings", fleetEstimatorWords(s)),
    kpi(`Energy saved (${METER_LABEL[s.meter]})`, `${fmt(saved, 0)} kWh`, "kpi-saved"),
    kpi("Avg hourly violation, activated", `${fmt(s.avg_hourly_violation_activated_k, 3)} K`, "kpi-violation"),
    kpi("… deactivated (reference)", `${fmt(s.avg_hourly_violation_deactivated_k, 3)} K`),
    kpi("Trains compared", `${s.trains.length}`, "kpi-trains"),
    kpi("Excluded", `${fmt(s.excluded_minutes / 60, 1)} train-hours`),
    kpi("Model, first-step error", health && health.mae_per_step_c.length && health.mae_per_step_c[0] !== null
      ? `${fmt(health.mae_per_step_c[0], 3)} K (bound ${fmt(health.bound_c, 2)} K)` : "–", "kpi-model"),
  ]);
}

function drawModelFlag(node, health) {
  node.hidden = !(health && (health.exceeds_bound || health.drift));
  if (node.hidden) { node.replaceChildren(); return; }
  const why = health.exceeds_bound
    ? `its online first-step error ${fmt(health.mae_per_step_c[0], 3)} K exceeds the ${fmt(health.bound_c, 2)} K bound`
    : `drift: ${health.drift_reason}`;
  sync(node, [document.createTextNode(`Model v${health.version}: ${why}. `), el("a", { href: "#/model", text: "Model health →" })]);
}

/** A horizontal legend above the plot area (never over an axis title). */
export const LEGEND_TOP = { orientation: "h", x: 0, xanchor: "left", y: 1.02, yanchor: "bottom" };

function drawEnergy(node, s) {
  let act = 0, deact = 0;
  const x = s.windows.map((w) => local(new Date(new Date(w.start).getTime() + s.window_min * 60e3).toISOString()));
  const yAct = s.windows.map((w) => (act += w.energy_activated_kwh));
  const yDeact = s.windows.map((w) => (deact += w.energy_deactivated_kwh));
  const traces = [
    { x, y: yDeact, name: "deactivated coaches", line: { color: COLOUR.deact, dash: DASH.deact, shape: "hv", width: 2 } },
    { x, y: yAct, name: "activated coaches", line: { color: COLOUR.act, dash: DASH.act, shape: "hv", width: 2.5 } },
  ];
  plot(node, traces, { margin: { t: 40, r: 20, l: 70, b: 60 }, hovermode: "x unified", legend: LEGEND_TOP,
    yaxis: { title: { text: "cumulative energy (kWh)", standoff: 8 }, rangemode: "tozero", automargin: true },
    xaxis: { title: { text: `time (${FLEET}), windows counted for both coaches of a train` }, automargin: true } },
  "Fleet energy, activated against deactivated coaches");
}

function drawTrainFigures(view, s) {
  const by = view.$("#train-sort").value;
  const trains = [...s.trains].sort(by === "id" ? (a, b) => naturalCompare(a.id, b.id)
    : (a, b) => (b.savings_pct ?? -Infinity) - (a.savings_pct ?? -Infinity));
  const names = trains.map((t) => t.id);
  drawSavingsPerTrain(view, trains);
  const label = (v) => (v === null || v === undefined ? "" : fmt(v, 3));
  plot(view.$("#violation-figure"), [
    { type: "bar", x: names, y: trains.map((t) => t.avg_hourly_violation_activated_k), name: "activated", marker: { color: COLOUR.act },
      text: trains.map((t) => label(t.avg_hourly_violation_activated_k)), textposition: "outside", cliponaxis: false },
    { type: "bar", x: names, y: trains.map((t) => t.avg_hourly_violation_deactivated_k), name: "deactivated",
      marker: { color: "#ffffff", line: { color: COLOUR.deact, width: 1.5 }, pattern: { shape: "x", fgcolor: COLOUR.deact, size: 6, solidity: 0.3 } },
      text: trains.map((t) => label(t.avg_hourly_violation_deactivated_k)), textposition: "outside", cliponaxis: false },
  ], { barmode: "group", margin: { t: 40, r: 20, l: 70, b: 50 }, legend: LEGEND_TOP,
    yaxis: { title: { text: "avg hourly violation (K)" }, rangemode: "tozero", automargin: true }, xaxis: { type: "category", title: { text: "train" } } },
  "Average hourly comfort violation per train");
}

/** One bar per train with its value written on it, its 95 % interval as error bars; a train
 *  without an interval hatched (confounded or too few days), one without a counted window marked
 *  so (no bar); and the same figures in words in the table below. A bar opens its train's pair
 *  comparison (by keyboard: the table's links). */
function drawSavingsPerTrain(view, trains) {
  const names = trains.map((t) => t.id);
  const hover = trains.map((t) => `${t.name}: ${savingsText(t)}<br>${estimatorWords(t)}<br>` +
    `${fmt(t.energy_activated_kwh, 1)} / ${fmt(t.energy_deactivated_kwh, 1)} kWh, ${fmt(t.excluded_minutes, 0)} min excluded`);
  const shown = (t) => t.counted_windows > 0 && t.savings_pct !== null;
  const ci = (t) => shown(t) && t.savings_ci95_pct;
  const common = { type: "bar", x: names, hovertext: hover, customdata: names, hovertemplate: "%{x}: %{hovertext}<extra></extra>",
    textposition: "outside", cliponaxis: false, textfont: { color: "#1b1f24" } };
  // each bar's value written above it (a trace without a bar gets no text: Plotly would draw
  // empty bars for it)
  const labels = (ys) => (ys.some((v) => v !== null) ? { y: ys, text: ys.map((v) => (v === null ? "" : `${fmt(v, 1)} %`)) } : { y: ys });
  const savings = view.$("#savings-figure");
  plot(savings, [
    { ...common, name: "with a 95 % interval (error bars)", ...labels(trains.map((t) => (ci(t) ? t.savings_pct : null))),
      marker: { color: BAR.solid, line: { color: BAR.solid, width: 1.5 } },
      error_y: { type: "data", symmetric: false, color: BAR.whisker, thickness: 1.5, width: 6,
        array: trains.map((t) => (ci(t) ? t.savings_ci95_pct[1] - t.savings_pct : null)),
        arrayminus: trains.map((t) => (ci(t) ? t.savings_pct - t.savings_ci95_pct[0] : null)) } },
    { ...common, name: "no interval (confounded or too few days)", ...labels(trains.map((t) => (shown(t) && !ci(t) ? t.savings_pct : null))),
      marker: { color: BAR.light, line: { color: BAR.solid, width: 1.5 }, pattern: { shape: "/", fgcolor: BAR.solid, bgcolor: BAR.light, size: 8, solidity: 0.25 } } },
  ], { barmode: "overlay", margin: { t: 40, r: 20, l: 70, b: 50 }, showlegend: true, legend: LEGEND_TOP,
    yaxis: { title: { text: "savings (%)" }, zeroline: true, zerolinecolor: "#5b6470", automargin: true }, xaxis: { title: { text: "train" }, type: "category" },
    annotations: trains.filter((t) => !t.counted_windows).map((t) => ({ x: t.id, y: 0, yanchor: "bottom", text: "none<br>counted",
      showarrow: false, font: { size: 11, color: "#5b6470" } })) }, "Savings per train");
  savings.removeAllListeners?.("plotly_click");
  savings.on("plotly_click", (event) => { location.hash = `#/train/${encodeURIComponent(event.points[0].customdata)}`; });
  sync(view.$("#train-savings tbody"), trains.map((t) => el("tr", { "data-train": t.id },
    el("td", {}, el("a", { href: `#/train/${encodeURIComponent(t.id)}`, text: t.id })),
    el("td", { class: "savings-text", text: savingsText(t) }),
    el("td", { text: t.counted_windows ? estimatorWords(t, true) : "–" }),
    el("td", { text: daysToTargetWords(t, true) }))));
}

function drawAttention(body, items) {
  sync(body, items.length ? items.map((a) => el("tr", { "data-coach": a.coach_id, "data-kind": a.kind },
    el("td", {}, el("a", { href: `#/coach/${encodeURIComponent(a.coach_id)}`, text: a.coach_id })),
    el("td", {}, statusBadge(a.kind === "comfort" ? "comfort-out" : a.status, KIND_LABEL[a.kind])),
    el("td", { text: a.detail })))
    : [el("tr", {}, el("td", { colspan: "3", text: "nothing: every coach is fed, on its setpoint and within comfort" }))]);
}

/** "Feed down since …" when there are live coaches and nothing arrives from any of them. */
export function drawFeedDown(node, coaches) {
  if (!node) return;
  const live = coaches.filter((c) => c.fleet === "live");
  const seen = live.map((c) => c.last_seen_at).filter(Boolean).sort();
  const down = live.length > 0 && seen.length > 0 && live.every((c) => c.status === "stale" || !c.last_seen_at);
  node.hidden = !down;
  const text = down
    ? `Live feed down since ${local(seen[seen.length - 1])} (wall time, Zurich): no telemetry arrives from any gateway. ` +
      "The coaches' HVACs follow their own T_rule once their last setpoint expires."
    : "";
  if (node.textContent !== text) node.textContent = text;
}
