// The live page of one fsrl run: events from /events (Server-Sent Events, served by fsrl
// itself), the model below, and a redraw at most every 200 ms. No library, no network other
// than this page's own server.
"use strict";

const S = {
  run: "",
  validation: new Map(), // RL episodes -> {success, collision, timeout, disc, nav}
  learner: [],           // one point per RL episode count: {x, lagMean, lagMax, ratio}
  throughput: [],        // {x, y}: RL episodes/s between learner messages
  actorRates: new Map(), // actor -> [{x, y}]
  lastLearner: null,     // {e, t, v}
  lastActor: new Map(),  // actor -> {e, t}
  procs: new Map(),      // sender -> {role, up, state, detail, episodes, metricsAt, error}
  target: 0,
  phase: "–",
  updated: 0,
};

function proc(sender, role) {
  let p = S.procs.get(sender);
  if (!p) {
    p = { role: role, up: null, state: "", detail: "", episodes: null, metricsAt: 0,
          counters: {}, error: "", errorAt: 0, leftAt: 0 };
    S.procs.set(sender, p);
  }
  return p;
}

// Counters of things that went wrong (rejected messages, failed writes or publications, lost
// episodes, ...): the last one that grew is the process's last error.
const ERROR_COUNTER = /rejected|failures|lost|bad_|timeouts|refused|skipped/;

function onMetrics(ev) {
  const v = ev.v, p = proc(ev.s, ev.role);
  p.metricsAt = Date.now();
  p.episodes = ev.e;
  for (const [k, x] of Object.entries(v)) {
    if (!ERROR_COUNTER.test(k)) continue;
    const before = p.counters[k];
    if (before !== undefined ? x > before : x > 0) {
      p.error = `${k.replace(/_/g, " ")}: ${x}`;
      p.errorAt = Date.now();
    }
    p.counters[k] = x;
  }
  if (ev.role === "evaluator" && v.validation_episode !== undefined) {
    S.validation.set(v.validation_episode, {
      success: v.validation_success_rate, collision: v.validation_collision_rate,
      timeout: v.validation_timeout_rate, disc: v.validation_discomfort,
      nav: v.validation_nav_time_s,
    });
  } else if (ev.role === "learner") {
    if (v.episodes_target !== undefined) S.target = v.episodes_target;
    if (v.imitation_done === 1) {
      S.phase = "RL";
      const last = S.lastLearner;
      if (last && ev.t > last.t && ev.e >= last.e && ev.e > 0) {
        S.throughput.push({ x: ev.e, y: (ev.e - last.e) / (ev.t - last.t) });
      }
      if (ev.e > 0 && (S.learner.length === 0 || S.learner[S.learner.length - 1].x < ev.e)) {
        S.learner.push({ x: ev.e, lagMean: v.policy_lag_mean, lagMax: v.policy_lag_max, ratio: v.updates_per_episode });
      }
      S.lastLearner = { e: ev.e, t: ev.t, v: v };
    } else if (v.imitation_epoch !== undefined) {
      S.phase = "imitation " + v.imitation_epoch + "/" + v.imitation_epochs;
    } else if (v.demo_episodes !== undefined) {
      S.phase = "demos " + v.demo_episodes + "/" + v.demo_target;
    }
  } else if (ev.role === "actor") {
    const last = S.lastActor.get(ev.s);
    const x = S.lastLearner ? S.lastLearner.e : 0;
    if (last && ev.t > last.t && ev.e >= last.e && x > 0) {
      if (!S.actorRates.has(ev.s)) S.actorRates.set(ev.s, []);
      S.actorRates.get(ev.s).push({ x: x, y: (ev.e - last.e) / (ev.t - last.t) });
    }
    S.lastActor.set(ev.s, { e: ev.e, t: ev.t });
  }
}

function onEvent(ev) {
  switch (ev.k) {
    case "run": S.run = ev.run; break;
    case "m": onMetrics(ev); break;
    case "s": {
      const p = proc(ev.s, ev.role);
      p.state = ev.state; p.detail = ev.detail;
      if (ev.state === "failed" || (ev.detail && /error|fail|refus|cannot/i.test(ev.detail))) {
        p.error = ev.detail; p.errorAt = Date.now();
      }
      break;
    }
    case "a": {
      const p = proc(ev.s, ev.role);
      p.up = ev.up;
      p.leftAt = ev.up ? 0 : Date.now();
      break;
    }
  }
  S.updated = Date.now();
  schedule();
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

function draw() {
  document.getElementById("run").textContent = S.run;
  const val = [...S.validation.entries()].sort((a, b) => a[0] - b[0]);
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
  const actors = [...S.actorRates.entries()].sort();
  chart("chart-throughput", [
    { name: "all actors", color: COLORS.total, pts: S.throughput },
    ...actors.map(([a, pts], i) => ({ name: a, color: ACTOR_COLORS[i % ACTOR_COLORS.length], pts: pts })),
  ], { leftMin: 0, empty: "no RL episodes yet" });
  chart("chart-lag", [
    { name: "lag mean", color: COLORS.lagMean, pts: S.learner.map(p => ({ x: p.x, y: p.lagMean })) },
    { name: "lag max", color: COLORS.lagMax, pts: S.learner.map(p => ({ x: p.x, y: p.lagMax })) },
    { name: "updates/episode (right)", color: COLORS.ratio, pts: S.learner.map(p => ({ x: p.x, y: p.ratio })), axis: "right" },
  ], { leftMin: 0, right: true, rightMin: 0, leftLabel: "versions", rightLabel: "updates", empty: "no RL episodes yet" });

  const set = (id, text) => { document.getElementById(id).textContent = text; };
  const last = S.lastLearner;
  set("phase", S.phase);
  set("episodes", last ? (S.target ? `${last.e} / ${S.target}` : String(last.e)) : "–");
  const actorsUp = [...S.procs.values()].filter(p => p.role === "actor" && p.up === true).length;
  set("actors-alive", String(actorsUp));
  const tp = S.throughput[S.throughput.length - 1];
  set("eps", tp ? tp.y.toFixed(2) : "–");
  set("lag", last && last.v.policy_lag_mean !== undefined ? last.v.policy_lag_mean.toFixed(2) : "–");
  set("ratio", last && last.v.updates_per_episode !== undefined ? last.v.updates_per_episode.toFixed(1) : "–");
  set("last-success", val.length ? `${val[val.length - 1][1].success.toFixed(2)} @ ${val[val.length - 1][0]}` : "–");

  const order = { learner: 0, evaluator: 1, actor: 2, monitor: 3 };
  const rows = [...S.procs.entries()].filter(([, p]) => p.role !== "monitor").sort((a, b) =>
    (order[a[1].role] - order[b[1].role]) || a[0].localeCompare(b[0], undefined, { numeric: true }));
  const tbody = document.getElementById("processes");
  tbody.textContent = "";
  for (const [sender, p] of rows) {
    const tr = document.createElement("tr");
    tr.dataset.sender = sender;
    tr.dataset.alive = String(p.up === true);
    const cell = (text, cls) => { const td = document.createElement("td"); td.textContent = text; if (cls) td.className = cls; tr.appendChild(td); return td; };
    cell(sender);
    const ago = t => `${Math.round((Date.now() - t) / 1000)} s ago`;
    const alive = cell(p.up === null ? "?" : p.up ? "alive" : p.leftAt ? "gone " + ago(p.leftAt) : "gone");
    const dot = document.createElement("span");
    dot.className = "dot " + (p.up ? "up" : "down");
    alive.prepend(dot);
    cell(p.episodes === null ? "–" : String(p.episodes));
    cell(p.metricsAt ? ago(p.metricsAt) : "–");
    cell(p.error ? `${p.error} (${ago(p.errorAt)})` : "", "err");
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
  if (ev.k === "run" && S.run) { location.reload(); return; }
  onEvent(ev);
};
setInterval(draw, 1000); // the "s ago" column
draw();
