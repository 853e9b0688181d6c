// The live page of fsrl runs: events from /events (Server-Sent Events, served by fsrl itself),
// one model per run below, and a redraw at most every 200 ms. The tiles and charts show the run
// selected in the runs table (the first one seen until another is chosen; kept in the URL's
// #run=...), the processes table every run's processes. No library, no network other than this
// page's own server.
"use strict";

const S = {
  every: false,          // a page of every run it sees (fsrl dashboard without --run)
  runs: new Map(),       // run id -> model (newRun)
  selected: decodeURIComponent((location.hash.match(/run=([^&]*)/) || [])[1] || ""),
  updated: 0,
};

function newRun(id) {
  return {
    id: id,
    validation: new Map(), // RL episodes -> {success, collision, timeout, disc, nav}
    learner: [],           // one point per RL episode count: {x, lagMean, lagMax, ratio}
    throughput: [],        // {x, y}: RL episodes/s between learner messages
    actorRates: new Map(), // actor -> [{x, y}]
    lastLearner: null,     // {e, t, v}
    lastActor: new Map(),  // actor -> {e, t}
    procs: new Map(),      // sender -> {role, up, state, error, ...}
    target: 0,
    phase: "–",
    watchError: "",        // this page cannot watch the run's liveliness: why ("" once it can)
  };
}

function runOf(id) {
  let r = S.runs.get(id);
  if (!r) {
    r = newRun(id);
    S.runs.set(id, r);
    if (!S.selected) S.selected = id;
  }
  return r;
}

function proc(R, sender, role) {
  let p = R.procs.get(sender);
  if (!p) {
    p = { role: role, up: null, state: "", episodes: null, metricsAt: 0,
          error: "", errorAt: 0, statusAt: 0, leftAt: 0 };
    R.procs.set(sender, p);
  }
  return p;
}

function onMetrics(R, ev) {
  const v = ev.v, p = proc(R, ev.s, ev.role);
  p.metricsAt = Date.now();
  p.episodes = ev.e;
  if (ev.role === "evaluator" && v.validation_episode !== undefined) {
    R.validation.set(v.validation_episode, {
      success: v.validation_success_rate, collision: v.validation_collision_rate,
      timeout: v.validation_timeout_rate, disc: v.validation_discomfort,
      nav: v.validation_nav_time_s,
    });
  } else if (ev.role === "learner") {
    if (v.episodes_target !== undefined) R.target = v.episodes_target;
    if (v.imitation_done === 1) {
      R.phase = "RL";
      const last = R.lastLearner;
      if (last && ev.t > last.t && ev.e >= last.e && ev.e > 0) {
        R.throughput.push({ x: ev.e, y: (ev.e - last.e) / (ev.t - last.t) });
      }
      if (ev.e > 0 && (R.learner.length === 0 || R.learner[R.learner.length - 1].x < ev.e)) {
        R.learner.push({ x: ev.e, lagMean: v.policy_lag_mean, lagMax: v.policy_lag_max, ratio: v.updates_per_episode });
      }
      R.lastLearner = { e: ev.e, t: ev.t, v: v };
    } else if (v.imitation_epoch !== undefined) {
      R.phase = "imitation " + v.imitation_epoch + "/" + v.imitation_epochs;
    } else if (v.demo_episodes !== undefined) {
      R.phase = "demos " + v.demo_episodes + "/" + v.demo_target;
    }
  } else if (ev.role === "actor") {
    const last = R.lastActor.get(ev.s);
    const x = R.lastLearner ? R.lastLearner.e : 0;
    if (last && ev.t > last.t && ev.e >= last.e && x > 0) {
      if (!R.actorRates.has(ev.s)) R.actorRates.set(ev.s, []);
      R.actorRates.get(ev.s).push({ x: x, y: (ev.e - last.e) / (ev.t - last.t) });
    }
    R.lastActor.set(ev.s, { e: ev.e, t: ev.t });
  }
}

// A heartbeat (proto::Status): the process's state, and its last error in `detail`.
function onStatus(R, ev) {
  const p = proc(R, ev.s, ev.role);
  p.state = ev.state;
  p.statusAt = Date.now();
  if (ev.detail !== p.error) {
    p.error = ev.detail;
    p.errorAt = Date.now();
  }
}

function onEvent(ev) {
  if (ev.k === "run") {
    S.every = ev.every === true;
    if (ev.run) runOf(ev.run);
  } else {
    const R = runOf(ev.r);
    switch (ev.k) {
      case "m": onMetrics(R, ev); break;
      case "s": onStatus(R, ev); break;
      case "a": {
        const p = proc(R, ev.s, ev.role);
        p.up = ev.up;
        p.leftAt = ev.up ? 0 : Date.now();
        break;
      }
      case "w": R.watchError = ev.detail; break;
    }
  }
  S.updated = Date.now();
  schedule();
}

function select(id) {
  S.selected = id;
  history.replaceState(null, "", "#run=" + encodeURIComponent(id));
  draw();
}

let pending = null;
function schedule() {
  if (pending === null) pending = setTimeout(() => { pending = null; draw(); }, 200);
}

// ---- charts -------------------------------------------------------------------------------
const COLORS = { success: "#1a9850", collision: "#d73027", timeout: "#9e9e9e", disc: "#f39c12",
                 nav: "#2c7fb8", total: "#1d2330", lagMean: "#7b3294", lagMax: "#c2a5cf", ratio: "#2c7fb8" };
const ACTOR_COLORS = ["#66c2a5", "#fc8d62", "#8da0cb", "#e78ac3", "#a6d854", "#ffd92f", "#e5c494", "#b3b3b3"];

function niceStep(span, n) {
  const raw = span / n, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const f = raw / mag;
  return (f <= 1 ? 1 : f <= 2 ? 2 : f <= 5 ? 5 : 10) * mag;
}

function fmt(x) {
  if (x === 0) return "0";
  const a = Math.abs(x);
  return a >= 1000 ? (x / 1000).toFixed(a >= 10000 ? 0 : 1) + "k" : a >= 10 ? x.toFixed(0) : a >= 1 ? x.toFixed(1) : x.toFixed(2);
}

// series: [{name, color, pts: [{x, y}], dots, axis: "left" | "right"}]
function chart(id, series, opt) {
  const svg = document.getElementById(id);
  const W = 560, H = 240, L = 46, R = opt.right ? 46 : 14, T = 24, B = 28;
  const all = series.flatMap(s => s.pts.filter(p => Number.isFinite(p.y)));
  svg.dataset.points = String(all.length);
  if (all.length === 0) {
    svg.innerHTML = `<text class="empty" x="${W / 2}" y="${H / 2}" text-anchor="middle">${opt.empty}</text>`;
    return;
  }
  const xs = all.map(p => p.x);
  let x0 = Math.min(0, ...xs), x1 = Math.max(...xs, x0 + 1);
  const range = side => {
    const ys = series.filter(s => (s.axis || "left") === side).flatMap(s => s.pts.map(p => p.y)).filter(Number.isFinite);
    let y0 = opt[side + "Min"] !== undefined ? opt[side + "Min"] : Math.min(0, ...ys);
    let y1 = opt[side + "Max"] !== undefined ? opt[side + "Max"] : Math.max(...ys, y0 + 1e-9) * 1.1;
    if (!(y1 > y0)) y1 = y0 + 1;
    return [y0, y1];
  };
  const [ly0, ly1] = range("left");
  const [ry0, ry1] = opt.right ? range("right") : [0, 1];
  const X = x => L + (x - x0) / (x1 - x0) * (W - L - R);
  const Y = (y, side) => side === "right" ? T + (1 - (y - ry0) / (ry1 - ry0)) * (H - T - B)
                                          : T + (1 - (y - ly0) / (ly1 - ly0)) * (H - T - B);
  let out = "";
  const ls = niceStep(ly1 - ly0, 4);
  for (let y = Math.ceil(ly0 / ls) * ls; y <= ly1 + 1e-9; y += ls) {
    out += `<line class="grid" x1="${L}" x2="${W - R}" y1="${Y(y)}" y2="${Y(y)}"/>`;
    out += `<text x="${L - 6}" y="${Y(y) + 4}" text-anchor="end">${fmt(y)}</text>`;
  }
  if (opt.right && series.some(s => s.axis === "right" && s.pts.some(p => Number.isFinite(p.y)))) {
    const rs = niceStep(ry1 - ry0, 4);
    for (let y = Math.ceil(ry0 / rs) * rs; y <= ry1 + 1e-9; y += rs) {
      out += `<text x="${W - R + 6}" y="${Y(y, "right") + 4}">${fmt(y)}</text>`;
    }
  }
  const xsStep = niceStep(x1 - x0, 5);
  for (let x = Math.ceil(x0 / xsStep) * xsStep; x <= x1 + 1e-9; x += xsStep) {
    out += `<line class="axis" x1="${X(x)}" x2="${X(x)}" y1="${H - B}" y2="${H - B + 4}"/>`;
    out += `<text x="${X(x)}" y="${H - B + 16}" text-anchor="middle">${fmt(x)}</text>`;
  }
  out += `<line class="axis" x1="${L}" x2="${W - R}" y1="${H - B}" y2="${H - B}"/>`;
  out += `<text x="${W - R}" y="${H - 2}" text-anchor="end">RL episodes</text>`;
  if (opt.leftLabel) out += `<text x="4" y="${T - 10}">${opt.leftLabel}</text>`;
  if (opt.rightLabel) out += `<text x="${W - 4}" y="${T - 10}" text-anchor="end">${opt.rightLabel}</text>`;
  let lx = L + 8;
  for (const s of series) {
    const side = s.axis || "left";
    const pts = s.pts.filter(p => Number.isFinite(p.y));
    if (pts.length === 0) continue;
    const d = pts.map(p => `${X(p.x).toFixed(1)},${Y(p.y, side).toFixed(1)}`).join(" ");
    out += `<polyline class="series" stroke="${s.color}" points="${d}"/>`;
    if (s.dots) for (const p of pts) out += `<circle cx="${X(p.x).toFixed(1)}" cy="${Y(p.y, side).toFixed(1)}" r="3" fill="${s.color}"/>`;
    out += `<rect x="${lx}" y="${T - 16}" width="10" height="3" fill="${s.color}"/><text class="legend" x="${lx + 14}" y="${T - 12}">${s.name}</text>`;
    lx += 22 + s.name.length * 6.2;
  }
  svg.innerHTML = out;
}

const ORDER = { learner: 0, evaluator: 1, actor: 2, monitor: 3 };
const ago = t => `${Math.round((Date.now() - t) / 1000)} s ago`;
const actorsUp = R => [...R.procs.values()].filter(p => p.role === "actor" && p.up === true).length;

function draw() {
  const R = S.runs.get(S.selected) || newRun(S.selected || "");
  document.getElementById("run").textContent = S.selected || (S.every ? "no run seen yet" : "");
  document.getElementById("scope").textContent = S.every ? `every run it sees (${S.runs.size})` : "";
  const val = [...R.validation.entries()].sort((a, b) => a[0] - b[0]);
  const vs = key => val.map(([x, v]) => ({ x: x, y: v[key] }));
  chart("chart-validation", [
    { name: "success", color: COLORS.success, pts: vs("success"), dots: true },
    { name: "collision", color: COLORS.collision, pts: vs("collision"), dots: true },
    { name: "timeout", color: COLORS.timeout, pts: vs("timeout"), dots: true },
  ], { leftMin: 0, leftMax: 1, empty: "no validation yet" });
  chart("chart-comfort", [
    { name: "Disc.", color: COLORS.disc, pts: vs("disc"), dots: true },
    { name: "Nav. Time (s, right)", color: COLORS.nav, pts: vs("nav"), dots: true, axis: "right" },
  ], { leftMin: 0, right: true, leftLabel: "Disc.", rightLabel: "s", empty: "no validation yet" });
  const actors = [...R.actorRates.entries()].sort();
  chart("chart-throughput", [
    { name: "all actors", color: COLORS.total, pts: R.throughput },
    ...actors.map(([a, pts], i) => ({ name: a, color: ACTOR_COLORS[i % ACTOR_COLORS.length], pts: pts })),
  ], { leftMin: 0, empty: "no RL episodes yet" });
  chart("chart-lag", [
    { name: "lag mean", color: COLORS.lagMean, pts: R.learner.map(p => ({ x: p.x, y: p.lagMean })) },
    { name: "lag max", color: COLORS.lagMax, pts: R.learner.map(p => ({ x: p.x, y: p.lagMax })) },
    { name: "updates/episode (right)", color: COLORS.ratio, pts: R.learner.map(p => ({ x: p.x, y: p.ratio })), axis: "right" },
  ], { leftMin: 0, right: true, rightMin: 0, leftLabel: "versions", rightLabel: "updates", empty: "no RL episodes yet" });

  const set = (id, text) => { document.getElementById(id).textContent = text; };
  const last = R.lastLearner;
  const episodes = X => X.lastLearner ? (X.target ? `${X.lastLearner.e} / ${X.target}` : String(X.lastLearner.e)) : "–";
  set("phase", R.phase);
  set("episodes", episodes(R));
  set("actors-alive", String(actorsUp(R)));
  const tp = R.throughput[R.throughput.length - 1];
  set("eps", tp ? tp.y.toFixed(2) : "–");
  set("lag", last && last.v.policy_lag_mean !== undefined ? last.v.policy_lag_mean.toFixed(2) : "–");
  set("ratio", last && last.v.updates_per_episode !== undefined ? last.v.updates_per_episode.toFixed(1) : "–");
  set("last-success", val.length ? `${val[val.length - 1][1].success.toFixed(2)} @ ${val[val.length - 1][0]}` : "–");

  // Runs whose liveliness this page cannot watch (their other events still come).
  const notes = [...S.runs.values()].filter(X => X.watchError).map(X => `${X.id}: ${X.watchError}`);
  const notices = document.getElementById("notices");
  notices.hidden = notes.length === 0;
  notices.textContent = notes.join("\n");

  const cell = (tr, text, cls) => { const td = document.createElement("td"); td.textContent = text; if (cls) td.className = cls; tr.appendChild(td); return td; };
  // The runs (a page of every run): one row each, the selected one highlighted; a click selects.
  document.getElementById("runs-section").hidden = !S.every;
  const runs = document.getElementById("runs");
  runs.textContent = "";
  for (const X of [...S.runs.values()].sort((a, b) => a.id.localeCompare(b.id, undefined, { numeric: true }))) {
    const tr = document.createElement("tr");
    tr.dataset.run = X.id;
    tr.dataset.validations = String(X.validation.size);
    tr.dataset.episodes = String(X.lastLearner ? X.lastLearner.e : 0);
    if (X.id === S.selected) tr.className = "selected";
    const b = document.createElement("button");
    b.textContent = X.id;
    b.onclick = () => select(X.id);
    cell(tr, "").appendChild(b);
    cell(tr, X.phase);
    cell(tr, episodes(X));
    const xv = [...X.validation.entries()].sort((a, b) => a[0] - b[0]);
    cell(tr, xv.length ? `${xv[xv.length - 1][1].success.toFixed(2)} @ ${xv[xv.length - 1][0]}` : "–");
    const procs = [...X.procs.values()].filter(p => p.role !== "monitor");
    cell(tr, `${procs.filter(p => p.up === true).length} / ${procs.length}`);
    const errors = procs.filter(p => p.error || p.state === "failed").length;
    cell(tr, errors ? String(errors) : "", "err");
    runs.appendChild(tr);
  }

  // Every run's processes: liveliness, and the state and last error of their heartbeats.
  const rows = [];
  for (const X of S.runs.values()) {
    for (const [sender, p] of X.procs) if (p.role !== "monitor") rows.push([X.id, sender, p]);
  }
  rows.sort((a, b) => a[0].localeCompare(b[0], undefined, { numeric: true }) ||
    (ORDER[a[2].role] - ORDER[b[2].role]) || a[1].localeCompare(b[1], undefined, { numeric: true }));
  const tbody = document.getElementById("processes");
  tbody.textContent = "";
  for (const [run, sender, p] of rows) {
    const tr = document.createElement("tr");
    tr.dataset.run = run;
    tr.dataset.sender = sender;
    tr.dataset.alive = String(p.up === true);
    tr.dataset.state = p.state;
    if (run === S.selected && S.every) tr.className = "selected";
    cell(tr, run);
    cell(tr, sender);
    const alive = cell(tr, p.up === null ? "?" : p.up ? "alive" : p.leftAt ? "gone " + ago(p.leftAt) : "gone");
    const dot = document.createElement("span");
    dot.className = "dot " + (p.up ? "up" : "down");
    alive.prepend(dot);
    // A process that is gone is no longer in its last state: say it was.
    cell(tr, p.state ? (p.up === false ? "was " + p.state : p.state) : "–", "state " + p.state);
    cell(tr, p.episodes === null ? "–" : String(p.episodes));
    cell(tr, p.metricsAt ? ago(p.metricsAt) : "–");
    cell(tr, p.error ? `${p.error} (${ago(p.errorAt)})` : "", "err");
    tbody.appendChild(tr);
  }
  document.getElementById("updated").textContent = S.updated ? "last event " + new Date(S.updated).toLocaleTimeString() : "";
}

const link = document.getElementById("link");
const source = new EventSource("events");
source.onopen = () => { link.textContent = "live"; link.className = "link up"; };
source.onerror = () => { link.textContent = "reconnecting"; link.className = "link down"; };
source.onmessage = m => {
  // A reconnected stream starts again from the history: the model is rebuilt from it.
  const ev = JSON.parse(m.data);
  if (ev.k === "run" && S.updated) { location.reload(); return; }
  onEvent(ev);
};
setInterval(draw, 1000); // the "s ago" column
draw();
