// The pair comparison: the pair's savings with their uncertainty, the trial plan, the chart and
// the windows as CSV. Every 30 s (the windows are 30 min); the plan every minute.
import { FLEET, METER_LABEL, fmt, kpi, local, sync, zurichToIso } from "../format.js";
import { drawExcludedReasons, drawPair, drawPairKey } from "../pair-chart.js";
import { pairSavingsKpis } from "../savings.js";
import { exportCsv } from "./overview.js";

export const PAIR_MS = 30_000;
export const PLAN_MS = 60_000;

/** The range asked for, as a query (`?start=…&end=…`; empty before the coach has a clock). */
function rangeQuery(view, clock) {
  const choice = view.$("#range").value;
  if (choice === "custom") {
    const start = view.$("#range-start").value;
    const end = view.$("#range-end").value;
    if (start && end) return `?start=${encodeURIComponent(zurichToIso(start))}&end=${encodeURIComponent(zurichToIso(end))}`;
  }
  const hours = choice === "custom" ? 24 : Number(choice);
  if (!clock) return "";
  const end = new Date(clock);
  const start = new Date(end.getTime() - hours * 3600e3);
  return `?start=${encodeURIComponent(start.toISOString())}&end=${encodeURIComponent(end.toISOString())}`;
}

export async function mount(view, trainId) {
  const train = await view.api(`/trains/${encodeURIComponent(trainId)}`);
  view.$("#train-title").textContent = `Train ${train.id}: ${train.name}`;
  const rangeSelect = view.$("#range");
  rangeSelect.addEventListener("change", () => {
    view.$("#custom-range").hidden = rangeSelect.value !== "custom";
    if (rangeSelect.value !== "custom") view.refresh(refresh);
  });
  view.$("#range-apply").addEventListener("click", () => view.refresh(refresh));
  const drawPlan = planControl(view, trainId);
  view.every(PLAN_MS, drawPlan);
  if (!train.activated.length || !train.deactivated.length) {
    view.$("#summary").textContent = "This train has no pair of an activated and a deactivated coach.";
    view.$("#train-export").disabled = true;
    return;
  }
  const [act, deact] = [train.activated[0], train.deactivated[0]];
  let last = null; // the last answers, redrawn when the temperature range is switched
  view.$("#whole-range").addEventListener("change", () => last && draw(...last));
  let query = "";
  view.$("#train-export").addEventListener("click", () => exportCsv(view, `/trains/${encodeURIComponent(trainId)}/comparison.csv${query}`));
  function draw(cmp, a, b, coach) {
    drawPair(view.$("#pair-figure"), cmp, a, b, act, deact, coach.comfort_band_k, view.$("#whole-range").checked);
  }
  async function refresh() {
    const coach = await view.api(`/coaches/${encodeURIComponent(act)}`);
    const q = rangeQuery(view, coach.clock);
    const [cmp, a, b] = await Promise.all([
      view.api(`/trains/${encodeURIComponent(trainId)}/comparison${q}`),
      view.api(`/coaches/${encodeURIComponent(act)}/timeseries${q}`),
      view.api(`/coaches/${encodeURIComponent(deact)}/timeseries${q}`),
    ]);
    if (view.left) return;
    query = q;
    view.$("#train-clock").textContent = coach.clock ? `${local(coach.clock)} (${FLEET})` : "";
    sync(view.$("#summary"), [
      ...pairSavingsKpis(cmp),
      kpi(`Avg hourly violation, activated ${act}`, `${fmt(cmp.avg_hourly_violation_k, 3)} K`),
      kpi(`Avg hourly violation, deactivated ${deact}`, `${fmt(cmp.baseline_violation_k, 3)} K`),
      kpi(`Energy activated / deactivated (${METER_LABEL[cmp.meter]})`, `${fmt(cmp.energy_activated_kwh, 1)} / ${fmt(cmp.energy_deactivated_kwh, 1)} kWh`),
      kpi("Excluded", `${fmt(cmp.excluded_minutes, 0)} min`)]);
    drawPairKey(view.$("#pair-key"), cmp);
    drawExcludedReasons(view.$("#excluded-reasons tbody"), cmp);
    last = [cmp, a, b, coach];
    draw(...last);
  }
  await view.every(PAIR_MS, refresh);
}

/** The pair view's trial plan: the one in force and a pending change with its effective time;
 *  operators change it (PUT, from the next switch hour). Returns the function that redraws it. */
function planControl(view, trainId) {
  const url = `/trains/${encodeURIComponent(trainId)}/plan`;
  const form = view.$("#plan-form");
  const error = view.$("#plan-error");
  let chosen = false; // the form starts on the plan in force, then keeps what the operator picks
  async function draw() {
    const p = await view.api(url);
    if (view.left) return;
    const today = p.activated_today ? `${p.activated_today} runs the layer today` : "neither coach runs the layer today";
    // a plan set before the train had any clock is in force from its first moment (1970)
    const since = p.effective_from && p.effective_from >= "2000" ? ` since ${local(p.effective_from).slice(0, 16)}` : "";
    const state = view.$("#plan-state");
    state.dataset.plan = p.plan;
    const stateText = `In force: ${p.plan}${since}, switch hour ${p.switch_hour}:00 (Zurich); ${today}.`;
    if (state.textContent !== stateText) state.textContent = stateText;
    const pending = view.$("#plan-pending");
    pending.dataset.plan = p.pending ? p.pending.plan : "";
    const pendingText = p.pending
      ? `Pending: ${p.pending.plan} from ${local(p.pending.effective_from).slice(0, 16)} (Zurich), set by ${p.pending.created_by}: ${p.pending.reason}`
      : `No change pending; the next service day starts at ${local(p.next_switch).slice(0, 16)} (Zurich).`;
    if (pending.textContent !== pendingText) pending.textContent = pendingText;
    if (!chosen) {
      view.$("#plan-select").value = p.plan;
      view.$("#plan-hour").value = String(p.switch_hour);
    }
  }
  form.addEventListener("input", () => { chosen = true; });
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    error.textContent = "";
    try {
      const p = await view.api(url, { method: "PUT", body: JSON.stringify({
        plan: view.$("#plan-select").value,
        switch_hour: Number(view.$("#plan-hour").value),
        reason: view.$("#plan-reason").value }) });
      view.$("#plan-message").textContent = p.message;
      view.$("#plan-reason").value = "";
      await draw();
    } catch (err) {
      if (!view.left) error.textContent = err.message;
    }
  });
  return draw;
}
