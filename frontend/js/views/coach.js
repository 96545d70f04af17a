// One coach: its status every 10 s; its prediction against what happened, its setpoints'
// sources, overrides and audit every 30 s; override, cancel and the layer switch, each once
// confirmed (naming the coach, the value and the duration); its telemetry as CSV.
import { ApiError } from "../api.js";
import { COLOUR, DECKS, DECK_COLOUR, SOURCE_STYLE, plot } from "../charts.js";
import { FLEET, WALL, badge, comfortBadge, el, fmt, kpi, local, sync } from "../format.js";
import { LEGEND_TOP, exportCsv } from "./overview.js";
import { session } from "../api.js";

export const STATUS_MS = 10_000;
export const HISTORY_MS = 30_000;
/** The override's fields: the API's name → the input and its label in words. */
const FIELDS = { t_ref_c: ["#ov-value", "T_ref"], duration_min: ["#ov-duration", "The duration"], reason: ["#ov-reason", "The reason"] };
/** The longest override the API takes. [min] */
const MAX_DURATION_MIN = 24 * 60;

export async function mount(view, coachId) {
  const path = `/coaches/${encodeURIComponent(coachId)}`;
  view.$("#coach-title").textContent = `Coach ${coachId}`;
  let coach = null;
  const form = view.$("#override-form");
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    clearFieldErrors(view);
    const value = view.$("#ov-value").valueAsNumber;
    const duration = view.$("#ov-duration").valueAsNumber;
    const reason = view.$("#ov-reason").value.trim();
    const problems = overrideProblems(coach, value, duration, reason);
    if (problems.length) { showFieldErrors(view, problems); return; }
    const until = coach?.clock ? `, until ${local(new Date(new Date(coach.clock).getTime() + duration * 60e3).toISOString()).slice(0, 16)} (${FLEET})` : "";
    if (!window.confirm(`Override coach ${coachId}: T_ref ${fmt(value, 1)} °C for ${duration} min${until}? Reason: ${reason}`)) return;
    try {
      await view.api(`${path}/override`, { method: "POST", body: JSON.stringify({ t_ref_c: value, duration_min: duration, reason }) });
      form.reset();
      view.$("#ov-status").textContent = `Override applied: ${fmt(value, 1)} °C for ${duration} min.`;
      await Promise.all([view.refresh(status), view.refresh(history)]);
    } catch (err) {
      if (!view.left) showFieldErrors(view, apiProblems(err));
    }
  });
  view.$("#layer-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const error = view.$("#layer-error");
    error.textContent = "";
    const reason = view.$("#layer-reason").value.trim();
    try {
      const now = await view.api(path);
      const question = now.ddpc_active
        ? `Switch the DDPC layer off for coach ${coachId}? It then follows the rule-based setpoint T_rule until switched on again. Reason: ${reason}`
        : `Switch the DDPC layer on for coach ${coachId}? Its setpoint is then planned by the model. Reason: ${reason}`;
      if (!window.confirm(question)) return;
      await view.api(`${path}/controller`, { method: "PUT", body: JSON.stringify({ active: !now.ddpc_active, reason }) });
      view.$("#layer-form").reset();
      await view.refresh(status);
    } catch (err) {
      if (!view.left) error.textContent = `Switching the layer failed: ${err.message}`;
    }
  });
  view.$("#coach-export").addEventListener("click", () => {
    const hours = Number(view.$("#export-hours").value);
    if (!coach?.clock) return exportCsv(view, `${path}/timeseries.csv`);
    const end = new Date(coach.clock);
    const start = new Date(end.getTime() - hours * 3600e3);
    return exportCsv(view, `${path}/timeseries.csv?start=${encodeURIComponent(start.toISOString())}&end=${encodeURIComponent(end.toISOString())}`);
  });

  async function status() {
    const c = await view.api(path);
    if (view.left) return;
    coach = c;
    view.$("#coach-clock").textContent = c.clock ? `${local(c.clock)} (${FLEET})` : "";
    const tiles = [
      kpi("Status", "", "kpi-status"),
      kpi("Layer", c.ddpc_active ? "activated" : "deactivated"),
      kpi(c.t_ref_applied === false ? "T_ref issued, not applied: the HVAC holds T_rule" : "T_ref", `${fmt(c.t_ref_c, 2)} °C`, "kpi-t-ref"),
      kpi("T_rule band", c.t_rule_c === null ? "–" : `${fmt(c.t_rule_c - c.comfort_band_k)} – ${fmt(c.t_rule_c + c.comfort_band_k)} °C`),
      kpi("Comfort now", "", "kpi-comfort"),
      kpi("Last solve", `${fmt(c.last_solve_ms, 3)} ms`)];
    tiles[0].querySelector(".value").replaceChildren(badge(c));
    tiles[4].querySelector(".value").replaceChildren(comfortBadge(c));
    sync(view.$("#coach-status"), tiles);
    const button = view.$("#layer-button");
    const label = c.ddpc_active ? "Switch the layer off" : "Switch the layer on";
    if (button.textContent !== label) button.textContent = label;
    const allowed = c.t_rule_c === null ? "" :
      `Allowed: ${fmt(c.t_rule_c - c.setpoint_band_k)} – ${fmt(c.t_rule_c + c.setpoint_band_k)} °C (T_rule ± ${fmt(c.setpoint_band_k, 0)} K, the driver's limit).`;
    if (view.$("#ov-band").textContent !== allowed) view.$("#ov-band").textContent = allowed;
  }

  async function history() {
    const [ts, sp, overrides, audit] = await Promise.all([
      view.api(`${path}/timeseries`),
      view.api(`${path}/setpoints`),
      view.api(`${path}/overrides`),
      view.api(`/audit?target=${encodeURIComponent(coachId)}&limit=50`),
    ]);
    if (view.left) return;
    drawPrediction(view.$("#prediction-figure"), ts, sp);
    drawSources(view.$("#sources-figure"), sp);
    sync(view.$("#overrides tbody"), overrides.length ? overrides.map((o) => el("tr", { "data-override": String(o.id ?? o.starts_at) },
      el("td", { "data-label": "T_ref", text: `${fmt(o.t_ref_c, 1)} °C` }),
      el("td", { "data-label": `When (${FLEET})`, text: `${local(o.starts_at).slice(11, 16)}–${local(o.ends_at).slice(11, 16)}` }),
      el("td", { "data-label": "By, why", text: `${o.created_by}: ${o.reason}` }),
      el("td", {}, o.active && session.me.role !== "viewer" ? cancelButton(view, coachId, o, () => Promise.all([view.refresh(status), view.refresh(history)]))
        : el("span", { text: o.active ? "active" : "ended" }))))
      : [el("tr", {}, el("td", { text: "none" }))]);
    sync(view.$("#coach-audit tbody"), audit.length ? audit.map((a) => el("tr", {},
      el("td", { "data-label": `Time (${WALL})`, text: local(a.time) }), el("td", { "data-label": "User", text: a.user }),
      el("td", { "data-label": "Action", text: a.action }), el("td", { "data-label": "Reason", text: a.reason }))) :
      [el("tr", {}, el("td", { text: "nothing yet" }))]);
  }
  view.every(HISTORY_MS, history);
  await view.every(STATUS_MS, status);
}

/** What is wrong with an override before it is sent, in words: [[field, message], …]. */
function overrideProblems(coach, value, duration, reason) {
  const out = [];
  if (!Number.isFinite(value)) out.push(["t_ref_c", "Enter T_ref in °C, e.g. 22.5."]);
  else if (coach && coach.t_rule_c !== null && Math.abs(value - coach.t_rule_c) > coach.setpoint_band_k + 1e-9) {
    out.push(["t_ref_c", `T_ref ${fmt(value, 1)} °C is outside T_rule ± ${fmt(coach.setpoint_band_k, 0)} K: between ${fmt(coach.t_rule_c - coach.setpoint_band_k)} and ${fmt(coach.t_rule_c + coach.setpoint_band_k)} °C now.`]);
  }
  if (!Number.isInteger(duration) || duration < 1 || duration > MAX_DURATION_MIN) {
    out.push(["duration_min", `The duration is whole minutes from 1 to ${MAX_DURATION_MIN} (a day).`]);
  }
  if (!reason) out.push(["reason", "Say why (the audit log keeps it)."]);
  return out;
}

/** The API's refusal as [[field, message], …]: a validation error per field in words, else
 *  the message on T_ref (the API's band check names it). */
function apiProblems(err) {
  if (err instanceof ApiError && Array.isArray(err.detail)) {
    return err.detail.map((d) => {
      const field = (d.loc || []).filter((x) => x !== "body")[0];
      const label = FIELDS[field]?.[1] || field;
      return [FIELDS[field] ? field : "t_ref_c", `${label}: ${String(d.msg).replace(/^Input should be /, "should be ")}.`];
    });
  }
  return [["t_ref_c", err.message]];
}

function clearFieldErrors(view) {
  view.$("#ov-error").textContent = "";
  view.$("#ov-status").textContent = "";
  for (const [input] of Object.values(FIELDS)) {
    view.$(input).removeAttribute("aria-invalid");
    view.$(input).setAttribute("aria-describedby", input === "#ov-value" ? "ov-band" : "");
  }
}

/** The problems in #ov-error (role=alert); each field named gets aria-invalid and is described
 *  by the message; focus moves to the first. */
function showFieldErrors(view, problems) {
  view.$("#ov-error").textContent = problems.map(([, message]) => message).join(" ");
  problems.forEach(([field]) => {
    const input = view.$(FIELDS[field][0]);
    input.setAttribute("aria-invalid", "true");
    input.setAttribute("aria-describedby", field === "t_ref_c" ? "ov-error ov-band" : "ov-error");
  });
  view.$(FIELDS[problems[0][0]][0]).focus();
}

function cancelButton(view, coachId, override, after) {
  const button = el("button", { class: "secondary", type: "button", text: "Cancel", "aria-label": `Cancel the override of ${coachId}` });
  button.addEventListener("click", async () => {
    const question = `Cancel the override of coach ${coachId} (T_ref ${fmt(override.t_ref_c, 1)} °C until ${local(override.ends_at).slice(11, 16)}, ${FLEET})? It returns to its planned setpoint.`;
    if (!window.confirm(question)) return;
    await view.api(`/coaches/${encodeURIComponent(coachId)}/override?reason=${encodeURIComponent("cancelled on the dashboard")}`, { method: "DELETE" });
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
    plot(node, [], { annotations: [{ text: "no completed prediction yet (the layer warms up for an hour)", showarrow: false, xref: "paper", yref: "paper", x: 0.5, y: 0.5 }],
      xaxis: { visible: false }, yaxis: { visible: false } }, "Last prediction against what happened");
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
  plot(node, traces, { margin: { t: 40, r: 20, l: 70, b: 60 }, legend: LEGEND_TOP, yaxis: { title: { text: "°C" }, automargin: true },
    xaxis: { title: { text: `time (${FLEET}), prediction made at ${local(sp.tick[index]).slice(11, 16)}` }, automargin: true },
    shapes: [{ type: "line", xref: "x", yref: "paper", x0: local(sp.tick[index]), x1: local(sp.tick[index]), y0: 0, y1: 1, line: { dash: "dot", color: "#444" } }] },
  "Last prediction against what happened");
}

function drawSources(node, sp) {
  const traces = Object.keys(SOURCE_STYLE).map((source) => {
    const idx = sp.source.map((s, i) => (s === source ? i : -1)).filter((i) => i >= 0);
    return { x: idx.map((i) => local(sp.tick[i])), y: idx.map((i) => sp.t_ref_c[i]), name: source, mode: "markers",
      marker: { color: SOURCE_STYLE[source].color, symbol: SOURCE_STYLE[source].symbol, size: 7 }, text: idx.map((i) => sp.reason[i]), hovertemplate: "%{x}<br>%{y:.2f} °C<br>%{text}" };
  });
  traces.push({ x: sp.tick.map(local), y: sp.t_rule_c, name: "T_rule", line: { color: COLOUR.band, dash: "dot" } });
  plot(node, traces, { margin: { t: 40, r: 20, l: 70, b: 60 }, legend: LEGEND_TOP, yaxis: { title: { text: "T_ref issued (°C)" }, automargin: true },
    xaxis: { title: { text: `time (${FLEET})` }, automargin: true } }, "Setpoint sources");
}
