// Savings with their uncertainty, in words and as tiles: the trial estimate of a pair, pooled
// for the fleet.
import { METER_LABEL, el, fmt, kpi, pct } from "./format.js";

/** Why a window does not count, in words (the API's `excluded_reason`). */
export const EXCLUDED_REASON = {
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
export const NO_WINDOWS = "no comparable windows yet";

/** Why a figure has no interval, in words (from its estimator and `savings_ci95_reason`). */
export function noIntervalWords(f) {
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
export function savingsParts(f) {
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
export function savingsText(f) {
  const p = savingsParts(f);
  return [p.value, p.interval].filter(Boolean).join(" ") + (p.qualifier ? ` — ${p.qualifier}` : "");
}

/** A tile's value node for a savings figure: the value large, interval and qualifier smaller. */
export function savingsValue(f) {
  const p = savingsParts(f);
  const node = el("div", { class: p.none ? "value none" : "value" }, el("span", { class: "main", text: p.value }));
  if (p.interval) node.append(" ", el("span", { class: "ci", text: p.interval }));
  if (p.qualifier) node.append(el("span", { class: "qualifier", text: ` — ${p.qualifier}` }));
  return node;
}

/** How a pair's savings are estimated, in words; `brief` where its savings say "confounded"
 *  already. */
export function estimatorWords(f, brief = false) {
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
export function daysToTargetWords(f, brief = false) {
  if (f.days_to_target === null || f.days_to_target === undefined) return "–";
  if (f.days_to_target === 0) return brief ? "reached" : "reached: ±2 points or better";
  return `about ${f.days_to_target} more day${f.days_to_target === 1 ? "" : "s"}${brief ? "" : " for ±2 points"}`;
}

/** How the fleet's figure is made: pooled over the trains with an interval, or the energy ratio. */
export function fleetEstimatorWords(s) {
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
export function savingsKpis(label, figures, id, sub = "") {
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

/** A tile whose value is words, not a figure (set smaller). */
export function wordy(tile) {
  tile.classList.add("wordy");
  return tile;
}

/** The pair's savings tiles: the estimate with its interval, how it is made, the days to ±2
 *  points, Guideline 14, and the energy ratio with the coaches' difference in it. */
export function pairSavingsKpis(cmp) {
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
