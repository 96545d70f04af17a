// A view's life: its own root in #view, its requests (stopped by an AbortController when it is
// left), its refresh timers, and the notice when a refresh fails and when it recovers.
import { aborted, api, ApiError } from "./api.js";
import { WALL } from "./format.js";

const wallClock = new Intl.DateTimeFormat("sv-SE", { timeZone: "Europe/Zurich", hour: "2-digit", minute: "2-digit", second: "2-digit" });

/** The status line under the header (role=status: the only live region besides alerts). */
function notice(text, failed) {
  const box = document.getElementById("refresh-status");
  box.textContent = text;
  box.classList.toggle("failed", failed);
  box.hidden = !text;
}

export class View {
  /** A view mounted from template `templateId` into #view (its root replaces the last one's). */
  constructor(templateId) {
    this.root = document.createElement("div");
    this.root.className = "view-root";
    this.root.append(document.getElementById(templateId).content.cloneNode(true));
    document.getElementById("view").replaceChildren(this.root);
    this.controller = new AbortController();
    this.timers = [];
    this.failing = false;
    this.recoveredTimer = null;
  }

  get signal() { return this.controller.signal; }
  get left() { return this.controller.signal.aborted; }
  $(selector) { return this.root.querySelector(selector); }

  /** The API's answer to `path`, stopped when the view is left. */
  api(path, options = {}) { return api(path, { ...options, signal: this.controller.signal }); }

  /** Runs `fn` now and every `ms` [ms] while the view is shown (not while the tab is hidden);
   *  returns the first run. A failure shows the notice; the next success says it recovered. */
  every(ms, fn) {
    const run = () => (this.left || document.hidden ? Promise.resolve() : this.refresh(fn));
    this.timers.push(setInterval(run, ms));
    return this.refresh(fn);
  }

  /** Runs `fn` once, noting a failure or a recovery. */
  async refresh(fn) {
    try {
      await fn();
      if (this.failing && !this.left) {
        this.failing = false;
        notice(`Refresh recovered at ${wallClock.format(new Date())} (${WALL}); the figures are current again.`, false);
        clearTimeout(this.recoveredTimer);
        this.recoveredTimer = setTimeout(() => notice("", false), 15_000);
      }
    } catch (err) {
      if (aborted(err) || this.left || (err instanceof ApiError && err.status === 401)) return;
      this.failing = true;
      clearTimeout(this.recoveredTimer);
      notice(`Refresh failed at ${wallClock.format(new Date())} (${WALL}): ${err.message}. Retrying; the figures shown are from the last successful refresh.`, true);
      console.warn(err);
    }
  }

  /** Leaves the view: its requests stop, its timers end. */
  unmount() {
    this.controller.abort();
    this.timers.forEach(clearInterval);
    clearTimeout(this.recoveredTimer);
    if (this.failing) notice("", false);
  }
}
