// The audit log (wall time: when it was done), every 30 s, rows updated in place.
import { el, local, sync } from "../format.js";

export const AUDIT_MS = 30_000;

export async function mount(view) {
  await view.every(AUDIT_MS, async () => {
    const rows = await view.api("/audit?limit=200");
    if (view.left) return;
    sync(view.$("#audit tbody"), rows.map((a) => el("tr", {},
      el("td", { "data-label": "Time (wall time, Zurich)", text: local(a.time) }), el("td", { "data-label": "User", text: a.user }),
      el("td", { "data-label": "Role", text: a.role }), el("td", { "data-label": "Action", text: a.action }),
      el("td", { "data-label": "Target", text: a.target }), el("td", { "data-label": "Reason", text: a.reason }),
      el("td", { "data-label": "Details", class: "details", text: JSON.stringify(a.detail) }))));
  });
}
