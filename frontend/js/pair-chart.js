// The pair's chart: the paper's experiment figure, live — both coaches' deck temperatures
// against the band, the weather, the energy and the 30-min savings on their own axis, with the
// strip of which coach ran the layer in each window and what was excluded.
import { COACH_SHADE, COLOUR, DASH, DECKS, DECK_COLOUR, EXCLUDED_SHADE, NEITHER_SHADE, plot } from "./charts.js";
import { FLEET, METER_LABEL, el, fmt, local } from "./format.js";
import { EXCLUDED_REASON } from "./savings.js";

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
export function drawPairKey(node, cmp) {
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
export function drawExcludedReasons(body, cmp) {
  const rows = Object.entries(cmp.excluded_minutes_by_reason || {}).sort((a, b) => b[1] - a[1]);
  const reference = cmp.windows.filter((w) => w.excluded_reason === "reference").length * cmp.window_min;
  if (reference) rows.push(["reference", reference]);
  const row = (reason, minutes) => el("tr", { "data-reason": reason },
    el("td", { text: EXCLUDED_REASON[reason] || reason }), el("td", { class: "num", text: fmt(minutes, 0) }));
  body.replaceChildren(...(rows.length ? rows.map(([r, m]) => row(r, m)) : [el("tr", {}, el("td", { colspan: "2", text: "none: every window counts" }))]));
  if (rows.length) body.append(el("tr", { class: "total" }, el("td", { text: "excluded in all" }), el("td", { class: "num", text: fmt(cmp.excluded_minutes, 0) })));
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

/** The temperature panels' range [°C]: around the comfort band and the decks while the coach is
 *  in service (regular mode with a T_rule), 0.5 K spare; null (Plotly's own, the night's too)
 *  when `whole` or when it never was. */
export function serviceRange(series, band, whole) {
  if (whole) return null;
  const values = [];
  for (const ts of series) {
    ts.time.forEach((_, i) => {
      if (ts.mode[i] !== "regular" || ts.t_rule_c[i] === null) return;
      values.push(ts.t_rule_c[i] - band, ts.t_rule_c[i] + band, ...ts.t_room_c[i].filter((v) => v !== null));
    });
  }
  if (!values.length) return null;
  return [Math.min(...values) - 0.5, Math.max(...values) + 0.5];
}

/** Draws the pair's chart; `whole`: the temperature panels over their whole range (the night's
 *  too), else around the band while in service. */
export function drawPair(node, cmp, a, b, act, deact, band, whole = false) {
  const mid = (w) => local(new Date(new Date(w.start).getTime() + cmp.window_min * 30e3).toISOString());
  const labelled = cmp.windows.length <= 24; // a value on each bar where there is room for it
  const traces = [
    ...temperatureTraces(b, "y", true, band),
    ...temperatureTraces(a, "y2", false, band),
    { x: a.time.map(local), y: a.t_amb_c, name: "T_amb", yaxis: "y3", line: { color: COLOUR.amb } },
    { x: a.time.map(local), y: a.ghi_w_m2, name: "global irradiance", yaxis: "y4", line: { color: COLOUR.ghi, dash: "dashdot" } },
    { x: b.time.map(local), y: cumulative(b, cmp.meter), name: `energy ${deact} (deactivated)`, yaxis: "y5", line: { color: COLOUR.deact, dash: DASH.deact, width: 2 } },
    { x: a.time.map(local), y: cumulative(a, cmp.meter), name: `energy ${act} (activated)`, yaxis: "y5", line: { color: COLOUR.act, dash: DASH.act, width: 2.5 } },
    { type: "bar", x: cmp.windows.map(mid), y: cmp.windows.map((w) => w.savings_pct), name: `${fmt(cmp.window_min, 0)}-min savings (%)`, yaxis: "y6",
      marker: { color: "#0072B2" }, width: cmp.window_min * 60e3 * 0.8,
      ...(labelled ? { texttemplate: "%{y:.1f}", textposition: "outside", cliponaxis: false, textfont: { size: 10, color: "#1b1f24" } } : {}) },
  ];
  const range = serviceRange([a, b], band, whole);
  const temperature = (text, domain) => ({ title: { text }, domain, anchor: "x", automargin: true, ...(range ? { range, autorange: false } : {}) });
  const layout = {
    margin: { t: 30, r: 80, l: 80, b: 130 }, hovermode: "x unified", legend: { orientation: "h", x: 0, y: -0.1, yanchor: "top" },
    xaxis: { title: { text: `time (${FLEET})` }, anchor: "y6", automargin: true },
    yaxis: temperature(`${deact} deact. (°C)`, [0.8, 1]),
    yaxis2: temperature(`${act} act. (°C)`, [0.61, 0.77]),
    yaxis3: { title: { text: "T_amb (°C)" }, domain: [0.42, 0.58], anchor: "x", automargin: true },
    yaxis4: { title: { text: "irradiance (W/m²)" }, overlaying: "y3", side: "right", anchor: "x", rangemode: "tozero", tickmode: "auto", automargin: true },
    yaxis5: { title: { text: `energy (kWh)<br>${METER_LABEL[cmp.meter]}` }, domain: [0.21, 0.39], anchor: "x", automargin: true, rangemode: "tozero" },
    yaxis6: { title: { text: "savings (%)" }, domain: [0, 0.18], anchor: "x", automargin: true, zeroline: true, zerolinecolor: "#5b6470" },
  };
  shadeWindows(layout, cmp, node.clientWidth, node.clientHeight);
  plot(node, traces, layout, `Pair ${act} (activated) against ${deact} (deactivated)`);
}
