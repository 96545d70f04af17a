// Charts: colours (≥ 3:1 on white, told apart with the common colour-vision deficiencies and by
// dash or marker shape too), Plotly's configuration (no cloud, PNG and SVG download) and each
// chart's data table (a toggle below it), so that bars and lines are reachable by keyboard and
// readable by a screen reader.
import { el } from "./format.js";

export const DECKS = ["up", "mid", "low"];
export const DECK_COLOUR = { up: "#D55E00", mid: "#009E73", low: "#0072B2" };
/** Activated green and solid, deactivated near-black and dashed: apart in luminance (4.9:1),
 *  hue and dash. */
export const COLOUR = { ref: "#000000", band: "#767676", amb: "#AA3377", ghi: "#9a6700", act: "#009E73", deact: "#1b1f24" };
export const DASH = { act: "solid", deact: "dash" };
/** The setpoint's source: colour and marker shape. */
export const SOURCE_STYLE = {
  ddpc: { color: "#009E73", symbol: "circle" },
  rule: { color: "#1b1f24", symbol: "x" },
  override: { color: "#5a32a3", symbol: "diamond" },
  fallback: { color: "#b42318", symbol: "triangle-up" },
};
/** The per-train savings bars: with a 95 % interval solid, without one hatched. */
export const BAR = { solid: "#0072B2", light: "#dcebf5", whisker: "#1b1f24" };
export const COACH_SHADE = ["#332288", "#994F00"];
export const NEITHER_SHADE = "#6b6b6b";
export const EXCLUDED_SHADE = "#b42318";

/** Plotly's configuration: no logo, no cloud sharing or Chart Studio, PNG and SVG download
 *  (named after the chart). */
export function plotConfig(filename) {
  const svg = {
    name: "Download plot as SVG",
    icon: window.Plotly.Icons.camera,
    click: (gd) => window.Plotly.downloadImage(gd, { format: "svg", filename }),
  };
  return {
    responsive: true, displaylogo: false, showSendToCloud: false, showEditInChartStudio: false,
    toImageButtonOptions: { format: "png", filename }, modeBarButtonsToAdd: [svg],
  };
}

/** Draws the chart into `node` and keeps its data table (a toggle below it) up to date;
 *  `title` names both. */
export function plot(node, traces, layout, title) {
  const filename = node.id.replace(/-figure$/, "");
  node.setAttribute("role", "figure");
  node.setAttribute("aria-label", `${title} (chart; its data as a table below)`);
  window.Plotly.react(node, traces, layout, plotConfig(filename));
  const table = dataTable(node, title);
  if (!table.hidden) fillTable(table, node.data || [], title);
}

function dataTable(node, title) {
  const id = `${node.id}-table`;
  let table = document.getElementById(id);
  if (table) return table;
  table = el("table", { id, class: "grid small data-table", hidden: "" });
  const button = el("button", { type: "button", class: "secondary table-toggle", "aria-expanded": "false", "aria-controls": id, text: "Show the data as a table" });
  button.addEventListener("click", () => {
    const open = table.hidden;
    table.hidden = !open;
    button.setAttribute("aria-expanded", String(open));
    button.textContent = open ? "Hide the data table" : "Show the data as a table";
    if (open) fillTable(table, node.data || [], title);
  });
  node.after(button, table);
  return table;
}

const cellText = (v) => (v === null || v === undefined || Number.isNaN(v) ? "–" : typeof v === "number" ? String(Math.round(v * 1000) / 1000) : String(v));

/** The traces as one table: a row per x value (in order of first appearance), a column per
 *  trace with points. */
function fillTable(table, traces, title) {
  const shown = traces.filter((t) => (t.y || []).length);
  const rows = new Map();
  shown.forEach((t, j) => (t.x || []).forEach((x, i) => {
    const key = String(x);
    if (!rows.has(key)) rows.set(key, new Array(shown.length).fill(null));
    rows.get(key)[j] = t.y[i];
  }));
  table.replaceChildren(
    el("caption", { text: `${title}: the chart's data` }),
    el("thead", {}, el("tr", {}, el("th", { scope: "col", text: "x" }), ...shown.map((t) => el("th", { scope: "col", text: t.name || "" })))),
    el("tbody", {}, ...[...rows].map(([x, ys]) => el("tr", {}, el("th", { scope: "row", text: x }), ...ys.map((y) => el("td", { class: "num", text: cellText(y) }))))));
}
