// Model health: the stored predictions against what happened, every minute.
import { COLOUR, plot } from "../charts.js";
import { el, fmt, naturalCompare, statusBadge, sync, kpi } from "../format.js";
import { LEGEND_TOP, modelHealth } from "./overview.js";

export const MODEL_MS = 60_000;

export async function mount(view) {
  view.$("#model-hours").addEventListener("change", () => view.refresh(refresh));
  async function refresh() {
    const h = await modelHealth(view, view.$("#model-hours").value);
    if (view.left) return;
    if (!h) {
      view.$("#model-kpis").textContent = "No model is active yet: the coaches follow the rule-based setpoint.";
      return;
    }
    view.$("#model-title").textContent = `Model health: version ${h.version}`;
    sync(view.$("#model-kpis"), [
      kpi("First-step MAE", h.mae_per_step_c[0] === undefined || h.mae_per_step_c[0] === null ? "–" : `${fmt(h.mae_per_step_c[0], 3)} K`, "kpi-first-step"),
      kpi("Bound", `${fmt(h.bound_c, 2)} K`),
      kpi("Within the bound", h.samples ? (h.exceeds_bound ? "no" : "yes") : "–", "kpi-within"),
      kpi("Samples", `${h.samples}`, "kpi-samples"),
      kpi("Prediction step", `${fmt(h.step_min, 0)} min`)]);
    const steps = h.mae_per_step_c.map((_, k) => (k + 1) * h.step_min);
    const models = await view.api("/models");
    const candidates = await Promise.all(models.filter((m) => m.state === "candidate")
      .map((m) => view.api(`/models/${m.version}/health?hours=${view.$("#model-hours").value}`)));
    if (view.left) return;
    plot(view.$("#mae-figure"), [
      { x: steps, y: h.mae_per_step_c, name: `active v${h.version}`, mode: "lines+markers", line: { color: COLOUR.act } },
      ...candidates.map((c) => ({ x: c.mae_per_step_c.map((_, k) => (k + 1) * c.step_min), y: c.mae_per_step_c,
        name: `candidate v${c.version} (shadow)`, mode: "lines+markers", line: { dash: "dot", color: "#5a32a3" }, marker: { symbol: "diamond" } })),
      { x: steps.length ? [steps[0], steps[steps.length - 1]] : [], y: [h.bound_c, h.bound_c], name: `bound ${fmt(h.bound_c, 2)} K`, mode: "lines", line: { color: "#b42318", dash: "dash" } },
    ], { margin: { t: 40, r: 20, l: 70, b: 50 }, legend: LEGEND_TOP,
      xaxis: { title: { text: "prediction horizon (min)" } }, yaxis: { title: { text: "mean absolute error (K)" }, rangemode: "tozero", automargin: true } },
    "Mean absolute error per prediction step");
    const coaches = [...h.coaches].sort((a, b) => naturalCompare(a.coach_id, b.coach_id));
    sync(view.$("#model-coaches tbody"), coaches.length ? coaches.map((c) => el("tr", { "data-coach": c.coach_id },
      el("td", { "data-label": "Coach" }, el("a", { href: `#/coach/${encodeURIComponent(c.coach_id)}`, text: c.coach_id })),
      el("td", { "data-label": "First-step MAE (K)", class: c.first_step_mae_c > h.bound_c ? "num expired" : "num", text: fmt(c.first_step_mae_c, 3) }),
      el("td", { "data-label": "Samples", class: "num", text: String(c.samples) }))) : [el("tr", {}, el("td", { text: "no prediction in the window yet" }))]);
    const mean = (v) => { const x = (v || []).filter((e) => e !== null); return x.length ? x.reduce((a, b) => a + b, 0) / x.length : null; };
    const beside = Object.fromEntries(candidates.map((c) => [c.version, c.beside]));
    sync(view.$("#model-versions tbody"), models.map((m) => el("tr", { "data-version": String(m.version), "data-state": m.state },
      el("td", { "data-label": "Version", text: `v${m.version}` }),
      el("td", { "data-label": "State" }, statusBadge({ active: "active", candidate: "override", retired: "inactive" }[m.state], m.state)),
      el("td", { "data-label": "Validation MAE (K)", class: "num", text: fmt(mean(m.validation_mae_per_step_c), 3) }),
      el("td", { "data-label": "Online MAE (K)", class: "num", text: fmt(mean(m.online_mae_per_step_c), 3) }),
      el("td", { "data-label": "Active model, same ticks (K)", class: "num", text: beside[m.version] ? fmt(mean(beside[m.version].mae_per_step_c), 3) : "–" }))));
  }
  await view.every(MODEL_MS, refresh);
}
