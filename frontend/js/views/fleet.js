// The coaches' list: filter, sort (header buttons with aria-sort, ids in natural order), the
// coaches every 10 s (rows updated in place), the replicas every minute.
import { FLEET, WALL, badge, comfortBadge, el, fmt, local, naturalCompare, sync, tRefCell } from "../format.js";
import { drawFeedDown } from "./overview.js";

export const COACHES_MS = 10_000;
export const REPLICAS_MS = 60_000;
/** The list's sort, kept while the dashboard is open. */
const sort = { key: "id", dir: 1 };

/** The value the coaches list sorts column ``key`` by: comfort by how far outside the band
 *  (unknown before any within it). */
function sortValue(coach, key) {
  if (key === "comfort") return coach.comfort ? coach.comfort.worst_excess_k : -1;
  return coach[key];
}

export async function mount(view) {
  const body = view.$("#coaches tbody");
  let coaches = [];
  const draw = () => {
    const text = view.$("#filter").value.toLowerCase();
    const status = view.$("#status-filter").value;
    const { key, dir } = sort;
    const rows = coaches
      .filter((c) => !status || c.status === status)
      .filter((c) => !text || [c.id, c.train_id, c.status, c.reason || ""].some((s) => s.toLowerCase().includes(text)))
      .sort((a, b) => dir * naturalCompare(sortValue(a, key), sortValue(b, key)) || naturalCompare(a.id, b.id));
    sync(body, rows.map((c) => {
      const temps = c.t_room_c ? c.t_room_c.map((t) => fmt(t)).join(" / ") : "–";
      const band = c.t_rule_c === null ? "–" : `${fmt(c.t_rule_c - c.comfort_band_k)} – ${fmt(c.t_rule_c + c.comfort_band_k)}`;
      return el("tr", { "data-coach": c.id },
        el("td", { "data-label": "Coach" }, el("a", { href: `#/coach/${encodeURIComponent(c.id)}`, text: c.id })),
        el("td", { "data-label": "Train", text: c.train_id }),
        el("td", { "data-label": "Layer", text: c.ddpc_active ? "activated" : "deactivated" }),
        el("td", { "data-label": "Status" }, badge(c)),
        el("td", { "data-label": "Mode", text: c.mode || "–" }),
        el("td", { "data-label": "Decks (°C)", class: "num", text: temps }),
        el("td", { "data-label": "Comfort", class: "comfort" }, comfortBadge(c)),
        el("td", { "data-label": "T_ref (°C)", class: "num" }, tRefCell(c)),
        el("td", { "data-label": "T_rule band (°C)", class: "num", text: band }),
        el("td", { "data-label": "Last solve (ms)", class: "num", text: fmt(c.last_solve_ms, 3) }),
        el("td", { "data-label": "Pair" }, el("a", { href: `#/train/${encodeURIComponent(c.train_id)}`, text: `compare ${c.train_id}` })));
    }));
    view.root.querySelectorAll("th[data-sort]").forEach((th) => {
      const on = th.dataset.sort === key;
      th.classList.toggle("sorted-asc", on && dir === 1);
      th.classList.toggle("sorted-desc", on && dir === -1);
      if (on) th.setAttribute("aria-sort", dir === 1 ? "ascending" : "descending"); else th.removeAttribute("aria-sort");
    });
  };
  view.$("#filter").addEventListener("input", draw);
  view.$("#status-filter").addEventListener("change", draw);
  view.root.querySelectorAll("th[data-sort] button").forEach((button) => button.addEventListener("click", () => {
    const key = button.closest("th").dataset.sort;
    sort.dir = sort.key === key ? -sort.dir : 1;
    sort.key = key;
    draw();
  }));
  view.every(REPLICAS_MS, async () => {
    const replicas = await view.api("/replicas");
    if (!view.left) drawReplicas(view.$("#replicas tbody"), replicas);
  });
  await view.every(COACHES_MS, async () => {
    const list = await view.api("/coaches");
    if (view.left) return;
    coaches = list;
    const clock = coaches.map((c) => c.clock).filter(Boolean).sort().pop();
    view.$("#fleet-clock").textContent = clock ? `${local(clock)} (${FLEET})` : "";
    drawFeedDown(view.$("#feed-down"), coaches);
    draw();
  });
}

/** The replicas that decided ticks in the last hour: which coaches each took, how many ticks. */
function drawReplicas(body, replicas) {
  sync(body, replicas.length ? replicas.map((r) => el("tr", { "data-replica": r.replica },
    el("td", { "data-label": "Replica", text: r.this ? `${r.replica} (this one)` : r.replica }),
    el("td", { "data-label": "Coaches", text: `${r.coaches.length}: ${r.coaches.join(", ")}` }),
    el("td", { "data-label": "Ticks", class: "num", text: String(r.ticks) }),
    el("td", { "data-label": `Last decision (${WALL})`, text: local(r.last_seen) })))
    : [el("tr", {}, el("td", { colspan: "4", text: "no ticks decided in the last hour" }))]);
}
