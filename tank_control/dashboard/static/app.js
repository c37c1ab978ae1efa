// tank_control dashboard page: trends of the signal topics (uPlot, zoom and pan), a faceplate
// per controller (SP/PV/OP, mode, alarms, gains, auto-tuner), a parameter panel per node; writes
// that change a controller ask for confirmation and can be undone. One WebSocket (/ws) to dashboard_node;
// the messages are described in tank_control/dashboard/server.py. Times: s of plant time.
'use strict';

(() => {
  const KEEP_S = 3600;            // history kept in the page [s of plant time]
  const NODE_ORDER = ['/controller', '/reference', '/plant'];
  const CHART_HEIGHT = 150;       // [px] of one trend's plot
  const COLORS = ['#1f77b4', '#d62728', '#2ca02c', '#9467bd', '#ff7f0e', '#8c564b',
                  '#e377c2', '#17becf'];

  const state = {
    paused: false,
    windowS: 300,
    view: null,         // null: the last windowS s (live); {t0, t1}: a zoomed/panned range
    units: {},          // channel -> engineering unit (the plant's, from dashboard_node)
    topics: {},         // topic -> {t: [], ch: {name: []}}
    limits: {},         // input channel -> [min, max]
    nodes: {},          // '/controller' -> node view (server.py, dashboard_node.py)
    charts: {},         // id -> {el, plot, title, sources: [{topic, channel, label}], limits}
    stats: {received: 0, byTopic: {}, lost: 0, missed: {}, batches: 0, frames: 0, fps: 0,
            restarts: 0},
    marks: [],          // state changes {node, machine, t, label} drawn on every trend
    dirty: false,
    nextId: 1,
  };
  window.tankDashboard = state;     // for tests and the curious

  const $ = (sel, root = document) => root.querySelector(sel);
  const el = (tag, attrs = {}, ...children) => {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k === 'class') e.className = v;
      else if (k.startsWith('data-')) e.setAttribute(k, v);
      else e[k] = v;
    }
    for (const c of children) e.append(c);
    return e;
  };
  const finite = (v) => typeof v === 'number' && Number.isFinite(v);
  const num = (v) => (v === 'inf' ? Infinity : v === '-inf' ? -Infinity : v === 'nan' ? NaN : v);

  // ---------------------------------------------------------------- access
  // The token of this dashboard start comes in the URL the node logs (?token=...); it is kept
  // for this tab (the runs page and back) and sent with every write. Without it, or when the
  // dashboard is read-only, the page shows the loop and refuses nothing itself: the server does.
  const TOKEN_KEY = 'tank_control.dashboard.token';
  const fromUrl = new URLSearchParams(location.search).get('token');
  if (fromUrl) sessionStorage.setItem(TOKEN_KEY, fromUrl);
  state.token = fromUrl || sessionStorage.getItem(TOKEN_KEY) || '';
  state.readOnly = !state.token;
  function showAccess(serverReadOnly) {
    state.readOnly = serverReadOnly || !state.token;
    const box = $('#access');
    box.textContent = serverReadOnly ? 'read-only dashboard'
      : state.token ? '' : 'read-only: open the URL with ?token= that dashboard_node logged to change values';
    box.hidden = !box.textContent;
    for (const view of Object.values(state.nodes)) setNode(view);
  }

  // ---------------------------------------------------------------- connection
  let ws = null;
  function connect() {
    const url = (location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws';
    ws = new WebSocket(url);
    ws.onopen = () => { $('#connection').textContent = 'live'; $('#connection').className = 'ok'; };
    ws.onclose = () => {
      $('#connection').textContent = 'disconnected, retrying…';
      $('#connection').className = 'bad';
      setTimeout(connect, 1000);
    };
    ws.onmessage = (ev) => handle(JSON.parse(ev.data));
  }
  function send(msg) {
    if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({...msg, token: state.token}));
  }

  function handle(msg) {
    switch (msg.type) {
      case 'hello':
        state.limits = msg.limits || {};
        state.units = msg.units || {};
        for (const name of Object.keys(state.nodes)) removeNode(name);
        for (const view of Object.values(msg.nodes)) setNode(view);
        refreshLimits();
        if (msg.robustness) { window.tankRobustness.update(msg.robustness); previewAgain(msg.robustness); }
        if (msg.missed) onMissed(msg.missed);
        state.marks = (msg.marks || []).slice();
        state.audit = [];
        $('#audit-rows').replaceChildren();
        for (const record of msg.audit || []) onAudit(record);
        state.serverReadOnly = !!msg.read_only;
        showAccess(state.serverReadOnly);
        break;
      case 'robustness': window.tankRobustness.update(msg); previewAgain(msg); break;
      case 'missed': onMissed(msg.missed); break;
      case 'mark': onMark(msg); break;
      case 'samples': onSamples(msg); break;
      case 'node': setNode(msg.node); break;
      case 'node_gone': removeNode(msg.node); break;
      case 'param': onParam(msg); break;
      case 'state': onState(msg); break;
      case 'diagnostics': onDiagnostics(msg); break;
      case 'limits': state.limits = msg.limits; refreshLimits(); break;
      case 'units': state.units = msg.units || {}; refreshUnits(); break;
      case 'set_result': onSetResult(msg); break;
      case 'command_result': onCommandResult(msg); break;
      case 'preview_result': onPreviewResult(msg); break;
      case 'audit': onAudit(msg.record); break;
      default: break;
    }
  }

  // ---------------------------------------------------------------- samples
  function onSamples(msg) {
    state.stats.batches += 1;
    state.stats.lost += msg.lost;
    for (const [topic, data] of Object.entries(msg.topics)) {
      let buf = state.topics[topic];
      if (!buf) buf = state.topics[topic] = {t: [], ch: {}};
      const n = data.t.length;
      if (buf.t.length && n && data.t[0] < buf.t[buf.t.length - 1] - 1e-9) {
        state.stats.restarts += 1;          // time went back: a new run (plant restarted)
        buf.t.length = 0;
        for (const col of Object.values(buf.ch)) col.length = 0;
      }
      const n0 = buf.t.length;
      for (let i = 0; i < n; i++) buf.t.push(data.t[i]);
      for (const [name, values] of Object.entries(data.ch)) {
        let col = buf.ch[name];
        if (!col) {
          col = buf.ch[name] = new Array(n0).fill(null);
          addChannel(topic, name);
        }
        for (let i = 0; i < n; i++) col.push(values[i]);
      }
      for (const col of Object.values(buf.ch)) while (col.length < buf.t.length) col.push(null);
      trim(buf);
      state.stats.received += n;
      state.stats.byTopic[topic] = (state.stats.byTopic[topic] || 0) + n;
    }
    $('#received').textContent = state.stats.received;
    $('#lost').textContent = state.stats.lost;
    state.dirty = true;
    schedule();
  }

  // Messages the publishers sent that never reached the dashboard node (the middleware's
  // message-lost count per topic, totals since the node started).
  function onMissed(missed) {
    state.stats.missed = missed;
    $('#missed').textContent = Object.values(missed).reduce((a, b) => a + b, 0);
  }

  // A state change; `update`: the last mark of that machine moves to the time the node
  // reported for it (a state entered by a command is timed at the next sample).
  function onMark(msg) {
    if (msg.update) {
      const same = state.marks.filter((m) => m.node === msg.node && m.machine === msg.machine);
      if (same.length) same[same.length - 1].t = msg.t;
    } else {
      state.marks.push({node: msg.node, machine: msg.machine, t: msg.t, label: msg.label});
      if (state.marks.length > 200) state.marks.splice(0, state.marks.length - 200);
    }
    state.dirty = true;
    schedule();
  }

  // A dashed vertical line with the state's name at each mark inside the x range.
  function drawMarks(u) {
    const [x0, x1] = [u.scales.x.min, u.scales.x.max];
    const ctx = u.ctx;
    ctx.save();
    ctx.strokeStyle = '#777';
    ctx.fillStyle = '#444';
    ctx.setLineDash([3, 3]);
    ctx.font = `${Math.round(10 * devicePixelRatio)}px sans-serif`;
    for (const m of state.marks) {
      if (!(m.t >= x0 && m.t <= x1)) continue;
      const x = Math.round(u.valToPos(m.t, 'x', true));
      ctx.beginPath();
      ctx.moveTo(x, u.bbox.top);
      ctx.lineTo(x, u.bbox.top + u.bbox.height);
      ctx.stroke();
      ctx.fillText(m.label, x + 3, u.bbox.top + 12 * devicePixelRatio);
    }
    ctx.restore();
  }

  function trim(buf) {
    const n = buf.t.length;
    if (n < 2) return;
    const cut = lowerBound(buf.t, buf.t[n - 1] - KEEP_S);
    if (cut > n / 2) {                        // amortised: drop in big pieces
      buf.t.splice(0, cut);
      for (const col of Object.values(buf.ch)) col.splice(0, cut);
    }
  }

  function lowerBound(a, x) {                 // first index with a[i] >= x
    let lo = 0; let hi = a.length;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (a[mid] < x) lo = mid + 1; else hi = mid; }
    return lo;
  }

  // ---------------------------------------------------------------- charts
  function unitText(channel) {
    const unit = channel === null ? '' : state.units[channel];
    return unit ? ` [${unit}]` : '';
  }

  function chartFor(id, title, channel) {
    let chart = state.charts[id];
    if (chart) return chart;
    const body = el('div', {class: 'plot'});
    const heading = el('h3', {}, title + unitText(channel));
    const box = el('div', {class: 'chart', id: 'chart-' + id, 'data-chart': id,
                           'data-points': '0'}, heading, body);
    $('#no-data')?.remove();
    const order = ['y-', 'u-', 'd'];
    const rank = (k) => order.findIndex((p) => k.startsWith(p));
    const after = (a, b) => a.toLowerCase() > b.toLowerCase();     // h before T_out
    const later = Object.keys(state.charts).filter((k) => rank(k) > rank(id) ||
      (rank(k) === rank(id) && after(k, id))).sort((a, b) => rank(a) - rank(b) || (after(a, b) ? 1 : -1));
    const before = later.length ? state.charts[later[0]].el : null;
    $('#trends').insertBefore(box, before);
    chart = state.charts[id] = {el: box, body, plot: null, title, channel, heading, sources: [],
                                limits: null};
    return chart;
  }

  function addChannel(topic, name) {
    let chart;
    if (topic === 'measurement') chart = chartFor('y-' + name, `output ${name}`, name);
    else if (topic === 'setpoint') chart = chartFor('y-' + name, `output ${name}`, name);
    else if (topic === 'manipulated') chart = chartFor('u-' + name, `input ${name}`, name);
    else chart = chartFor('d', 'disturbances', null);
    const label = {measurement: `${name} measured`, setpoint: `${name} setpoint`,
                   manipulated: name, disturbance: name}[topic] || `${topic} ${name}`;
    chart.sources.push({topic, channel: name, label});
    chart.sources.sort((a, b) => (a.topic === 'measurement' ? -1 : 0) - (b.topic === 'measurement' ? -1 : 0));
    if (topic === 'manipulated') chart.limits = state.limits[name] || null;
    rebuild(chart);
  }

  function refreshLimits() {
    for (const [id, chart] of Object.entries(state.charts)) {
      if (!id.startsWith('u-')) continue;
      const limits = state.limits[id.slice(2)] || null;
      if (JSON.stringify(limits) !== JSON.stringify(chart.limits)) {
        chart.limits = limits;
        rebuild(chart);
      }
    }
  }

  function refreshUnits() {
    for (const chart of Object.values(state.charts)) {
      chart.heading.textContent = chart.title + unitText(chart.channel);
    }
    for (const view of Object.values(state.nodes)) if (isController(view)) renderFaceplate(view);
  }

  function limitSeries(chart) {
    if (!chart.limits) return [];
    const [lo, hi] = chart.limits.map(num);
    const out = [];
    if (finite(lo)) out.push({label: 'min', value: lo});
    if (finite(hi)) out.push({label: 'max', value: hi});
    return out;
  }

  function rebuild(chart) {
    if (chart.plot) chart.plot.destroy();
    const series = [{label: 't [s]'}];
    chart.sources.forEach((s, i) => series.push({
      label: s.label, stroke: COLORS[i % COLORS.length], width: 1.5, spanGaps: true,
      dash: s.topic === 'setpoint' ? [6, 4] : undefined,
    }));
    for (const l of limitSeries(chart)) {
      series.push({label: l.label, stroke: '#999', width: 1, dash: [2, 3], points: {show: false}});
    }
    const width = Math.max(300, chart.body.clientWidth || chart.el.clientWidth || 600);
    // the legend shows the values at the cursor; the cursor is shared by every trend; a drag
    // across a trend zooms all of them to that time range (◀ ▶ pan, "live" follows again)
    const opts = {width, height: CHART_HEIGHT, series,
                  scales: {x: {time: false, range: (u, lo, hi) => (state.view
                    ? [state.view.t0, state.view.t1] : [lo, hi])},
                           y: {range: (u) => yRange(chart, u)}},
                  axes: [{}, {size: 60}],
                  legend: {live: true},
                  cursor: {drag: {x: true, y: false, setScale: false}, sync: {key: 'trends'}},
                  hooks: {draw: [drawMarks], setSelect: [zoomToSelection]}};
    chart.plot = new uPlot(opts, series.map(() => []), chart.body);
    state.dirty = true;
    schedule();
  }

  // The y range of the signals themselves; a limit line widens it only when it lies near them
  // (an input limit of 1e4 would otherwise flatten the input to a line at 0).
  function yRange(chart, u) {
    let lo = Infinity, hi = -Infinity;
    for (let k = 1; k <= chart.sources.length; k++) {
      for (const v of u.data[k] || []) {
        if (v !== null && finite(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
      }
    }
    if (lo === Infinity) return [0, 1];
    const span = Math.max(hi - lo, Math.abs(hi) * 0.05, 1e-9);
    for (const l of limitSeries(chart)) {
      if (l.value >= lo - span && l.value <= hi + span) {
        lo = Math.min(lo, l.value); hi = Math.max(hi, l.value);
      }
    }
    const pad = Math.max(hi - lo, span) * 0.05;
    return [lo - pad, hi + pad];
  }

  // ---------------------------------------------------------------- zoom and pan
  function zoomToSelection(u) {
    if (u.select.width < 5) return;
    const t0 = u.posToVal(u.select.left, 'x');
    const t1 = u.posToVal(u.select.left + u.select.width, 'x');
    u.setSelect({left: 0, top: 0, width: 0, height: 0}, false);
    if (t1 > t0) setView({t0, t1});
  }

  function setView(view) {
    state.view = view;
    $('#live').classList.toggle('active', !view);
    $('#view-range').textContent = view
      ? `t ${view.t0.toFixed(1)} … ${view.t1.toFixed(1)} s (zoomed)` : `last ${state.windowS} s`;
    state.dirty = true;
    schedule();
  }

  function pan(direction) {
    const tEnd = latestTime();
    if (!Number.isFinite(tEnd)) return;
    const view = state.view || {t0: tEnd - state.windowS, t1: tEnd};
    const shift = (view.t1 - view.t0) / 2 * direction;
    if (direction > 0 && view.t1 + shift >= tEnd) { setView(null); return; }
    setView({t0: view.t0 + shift, t1: view.t1 + shift});
  }

  function upperBound(a, x) {                 // first index with a[i] > x
    let lo = 0; let hi = a.length;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (a[mid] <= x) lo = mid + 1; else hi = mid; }
    return lo;
  }

  // Union of the sources' times inside the window (or the zoomed range), each series null where
  // it has no sample.
  function windowData(chart, tLatest) {
    const tStart = state.view ? state.view.t0 : tLatest - state.windowS;
    const tEnd = state.view ? state.view.t1 : tLatest;
    const parts = chart.sources.map((s) => {
      const buf = state.topics[s.topic];
      if (!buf) return {t: [], v: [], i: 0, end: 0};
      const i = lowerBound(buf.t, tStart);
      return {t: buf.t, v: buf.ch[s.channel] || [], i, end: upperBound(buf.t, tEnd)};
    });
    const xs = [];
    const ys = parts.map(() => []);
    for (;;) {
      let tMin = Infinity;
      for (const p of parts) if (p.i < p.end && p.t[p.i] < tMin) tMin = p.t[p.i];
      if (tMin === Infinity) break;
      xs.push(tMin);
      parts.forEach((p, k) => {
        if (p.i < p.end && p.t[p.i] === tMin) { ys[k].push(p.v[p.i]); p.i += 1; }
        else ys[k].push(null);
      });
    }
    const data = [xs, ...ys];
    for (const l of limitSeries(chart)) data.push(xs.map(() => l.value));
    return data;
  }

  function latestTime() {
    let t = -Infinity;
    for (const buf of Object.values(state.topics)) {
      if (buf.t.length) t = Math.max(t, buf.t[buf.t.length - 1]);
    }
    return t;
  }

  let scheduled = false;
  function schedule() {
    if (scheduled || state.paused) return;
    scheduled = true;
    requestAnimationFrame(draw);
  }

  function draw() {
    scheduled = false;
    if (state.paused || !state.dirty) return;
    state.dirty = false;
    const tEnd = latestTime();
    if (!Number.isFinite(tEnd)) return;
    for (const chart of Object.values(state.charts)) {
      if (!chart.plot) continue;
      const data = windowData(chart, tEnd);
      chart.plot.setData(data);
      chart.el.dataset.points = String(data[0].length);
    }
    $('#time').textContent = tEnd.toFixed(2);
    updateFaceplates();
    state.stats.frames += 1;
  }

  let framesBefore = 0;
  setInterval(() => {
    state.stats.fps = state.stats.frames - framesBefore;
    framesBefore = state.stats.frames;
    $('#fps').textContent = state.stats.fps;
  }, 1000);

  window.addEventListener('resize', () => {
    for (const chart of Object.values(state.charts)) {
      if (chart.plot) chart.plot.setSize({width: Math.max(300, chart.body.clientWidth), height: CHART_HEIGHT});
    }
    measureHeader();
  });
  function measureHeader() {
    document.documentElement.style.setProperty('--header-h', `${$('header').offsetHeight}px`);
  }
  measureHeader();
  $('#pan-left').addEventListener('click', () => pan(-1));
  $('#pan-right').addEventListener('click', () => pan(1));
  $('#live').addEventListener('click', () => setView(null));

  $('#pause').addEventListener('click', () => {
    state.paused = !state.paused;
    $('#pause').textContent = state.paused ? 'Resume' : 'Pause';
    $('#pause').classList.toggle('active', state.paused);
    if (!state.paused) { state.dirty = true; schedule(); }
  });
  $('#window').addEventListener('change', () => {
    const w = parseFloat($('#window').value);
    if (finite(w) && w > 0) {
      state.windowS = Math.min(w, KEEP_S);
      setView(null);
    }
  });
  state.windowS = Math.min(parseFloat($('#window').value) || 300, KEEP_S);
  setView(null);

  // ---------------------------------------------------------------- nodes
  function nodeRank(name) {
    const i = NODE_ORDER.indexOf(name);
    return i < 0 ? NODE_ORDER.length : i;
  }

  function formatValue(v) {
    if (Array.isArray(v)) return JSON.stringify(v);
    return String(v);
  }

  // A number as a reader takes it in: 4 significant digits, exponent only when far from 1.
  function fmt(v) {
    v = num(v);
    if (typeof v !== 'number') return String(v);
    if (!finite(v)) return v > 0 ? '∞' : v < 0 ? '−∞' : 'nan';
    if (v === 0) return '0';
    const a = Math.abs(v);
    if (a >= 1e5 || a < 1e-3) return v.toExponential(2).replace('e+', 'e');
    return String(Number(v.toPrecision(4)));
  }

  // "allowed ..." of the node's own constraint text ("double; allowed [0, 1e+12]"), else the
  // descriptor's range, written readably.
  function rangeText(p) {
    const parts = [];
    const allowed = /;\s*allowed\s+(.*)$/.exec(p.constraints || '');
    if (allowed && !allowed[1].startsWith('one of') && !allowed[1].startsWith('any ')) {
      parts.push(allowed[1]);
    } else if (!allowed && p.range) {
      const [lo, hi] = p.range.map(num);
      parts.push(`[${fmt(lo)}, ${fmt(hi)}]`);
    }
    if (p.read_only) parts.push('read-only');
    return parts.join(' ');
  }

  function choicesOf(p) {
    const m = /allowed one of (.*)$/.exec(p.constraints || '');
    return m && p.type === 4 ? m[1].split(', ') : null;
  }

  function isController(view) {
    return !!(view && view.loaded && view.params.controller && view.params.input_names);
  }

  // A write that changes a controller (mode, gains, limits, ...) asks for confirmation first.
  function needsConfirm(node) {
    return isController(state.nodes[node]);
  }

  // Parameters sorted for reading: plain names first, then the dotted groups.
  function paramOrder(names) {
    return names.sort((a, b) => (a.includes('.') - b.includes('.')) || (a < b ? -1 : a > b ? 1 : 0));
  }

  function setNode(view) {
    state.nodes[view.name] = view;
    $('#no-nodes')?.remove();
    const id = 'node-' + view.name.replace(/[^A-Za-z0-9_-]/g, '_');
    const box = el('div', {class: 'node', id, 'data-node': view.name});
    const diag = el('span', {class: 'diag', 'data-node': view.name});
    box.append(el('h2', {}, view.name, diag));
    if (view.diagnostics && view.diagnostics.message !== undefined) showDiagnostics(diag, view.diagnostics);
    const controller = isController(view);
    if (controller) renderFaceplate(view);
    else removeFaceplate(view.name);
    if (view.commands.length && !controller) box.append(commandButtons(view));
    if (!controller) box.append(...stateRows(view));
    if (!view.loaded) {
      box.append(el('p', {class: 'hint'}, 'reading parameters…'));
    } else {
      const table = el('table', {class: 'params'});
      for (const name of paramOrder(Object.keys(view.params))) {
        table.append(paramRow(view, name, view.params[name]));
      }
      box.append(table);
    }
    const old = document.getElementById(id);
    if (old) old.replaceWith(box);
    else {
      const later = [...document.querySelectorAll('#nodes .node')].find((n) => {
        const other = n.getAttribute('data-node');
        return nodeRank(other) > nodeRank(view.name) ||
          (nodeRank(other) === nodeRank(view.name) && other > view.name);
      });
      $('#nodes').insertBefore(box, later || null);
    }
  }

  function commandButtons(view) {
    const cmds = el('div', {class: 'commands'});
    for (const command of view.commands) {
      const button = el('button', {type: 'button', 'data-node': view.name, 'data-command': command,
                                   disabled: state.readOnly},
                        command.replace(/_/g, ' '));
      const result = el('span', {class: 'command-result', 'data-node': view.name, 'data-command': command});
      button.addEventListener('click', () => {
        result.textContent = '…';
        send({type: 'command', node: view.name, command, id: state.nextId++});
      });
      cmds.append(el('span', {}, button, result));
    }
    return cmds;
  }

  function stateRows(view) {
    return Object.entries(view.states || {}).map(([topic, value]) =>
      el('div', {class: 'state-row'}, `${topic}: `,
         el('b', {class: 'state', 'data-node': view.name, 'data-topic': topic}, value)));
  }

  function removeNode(name) {
    delete state.nodes[name];
    document.querySelector(`#nodes .node[data-node="${CSS.escape(name)}"]`)?.remove();
    removeFaceplate(name);
  }

  // An editor for one parameter: a select for a choice, a toggle for a boolean, else text.
  function paramInput(view, name, p, extraClass = '') {
    const attrs = {'data-node': view.name, 'data-param': name};
    const disabled = p.read_only || state.readOnly;
    const choices = choicesOf(p);
    let input;
    if (p.type === 1) {
      input = el('input', {type: 'checkbox', class: `toggle ${extraClass}`, checked: p.value === true,
                           disabled, ...attrs});
      input.addEventListener('change', () => requestWrite(view.name, name, input.checked ? 'true' : 'false'));
    } else if (choices) {
      input = el('select', {class: extraClass, disabled, ...attrs});
      for (const c of choices) input.append(el('option', {value: c}, c));
      input.value = p.value;
      input.addEventListener('change', () => requestWrite(view.name, name, input.value));
    } else {
      input = el('input', {type: 'text', class: extraClass, value: formatValue(p.value), disabled,
                           spellcheck: false, ...attrs});
      input.addEventListener('change', () => requestWrite(view.name, name, input.value));
      input.addEventListener('keydown', (ev) => {
        if (ev.key === 'Escape') { input.value = formatValue(state.nodes[view.name].params[name].value); input.blur(); }
      });
    }
    return input;
  }

  function paramRow(view, name, p) {
    const attrs = {'data-node': view.name, 'data-param': name};
    const reason = el('div', {class: 'reason', ...attrs});
    return el('tr', {...attrs},
      el('td', {class: 'name', title: p.description}, name, el('div', {class: 'desc'}, p.description)),
      el('td', {}, paramInput(view, name, p), reason),
      el('td', {class: 'range', title: p.constraints || ''}, rangeText(p)));
  }

  // ---------------------------------------------------------------- faceplates
  const faceplateId = (node) => 'faceplate-' + node.replace(/[^A-Za-z0-9_-]/g, '_');
  const GAIN = /^(kp|ki|kd|ti|td|b|c)(_\w+)?$/;

  function removeFaceplate(node) {
    document.getElementById(faceplateId(node))?.remove();
  }

  function loopsOf(view) {
    const outs = view.params.output_names?.value || [];
    const ins = view.params.input_names?.value || [];
    return ins.map((u, i) => ({y: outs[i] ?? outs[0], u}));
  }

  function meter(kind, channel, testid) {
    return el('div', {class: 'fp-row', 'data-testid': testid, 'data-channel': channel},
      el('span', {class: 'fp-value'}, '–'), el('span', {class: 'fp-unit'}, state.units[channel] || ''),
      el('div', {class: `bar ${kind}`}, el('div', {class: 'fill'}), el('div', {class: 'sp-mark', hidden: true})),
      el('span', {class: 'bar-limits'}, ''));
  }

  function renderFaceplate(view) {
    const id = faceplateId(view.name);
    const old = document.getElementById(id);
    if (old && old.contains(document.activeElement) && document.activeElement !== document.body) {
      return;          // being edited: values are refreshed by showValue
    }
    const p = view.params;
    const box = el('div', {class: 'faceplate', id, 'data-testid': `faceplate-${view.name}`,
                           'data-node': view.name});
    const status = el('span', {class: 'fp-status', 'data-testid': 'status'});
    box.append(el('h2', {}, view.name, el('span', {class: 'kind'}, String(p.controller.value)), status));
    // mode: auto/manual toggle; the manual output is editable only in manual
    const controls = el('div', {class: 'fp-controls'});
    if (p.mode) {
      const mode = String(p.mode.value);
      const toggle = el('span', {class: 'mode-toggle', 'data-testid': 'mode', 'data-mode': mode,
                                 role: 'group'});
      for (const choice of choicesOf(p.mode) || ['auto', 'manual']) {
        const b = el('button', {type: 'button', 'data-mode': choice, disabled: state.readOnly || p.mode.read_only},
                     choice[0].toUpperCase() + choice.slice(1));
        b.setAttribute('aria-pressed', String(choice === mode));
        b.addEventListener('click', () => { if (choice !== String(state.nodes[view.name].params.mode.value)) requestWrite(view.name, 'mode', choice); });
        toggle.append(b);
      }
      controls.append(el('label', {}, 'mode ', toggle));
    } else {           // a kind without a manual mode (e.g. two_loop_pi): always automatic
      controls.append(el('label', {}, 'mode ', el('span', {class: 'mode-toggle', 'data-testid': 'mode',
        'data-mode': 'auto', title: 'this controller kind has no manual mode'}, 'auto (no manual mode)')));
    }
    if (p.manual_output) {
      const input = paramInput(view, 'manual_output', p.manual_output, 'fp-input');
      input.setAttribute('data-testid', 'manual-output');
      if (String(p.mode?.value) !== 'manual') input.disabled = true;
      controls.append(el('label', {title: 'editable in manual mode'}, 'manual output ', input));
    }
    box.append(controls);
    for (const loop of loopsOf(view)) {
      box.append(el('div', {class: 'loop', 'data-loop': loop.y},
        el('div', {class: 'loop-name'}, `${loop.y} ← ${loop.u}`),
        el('span', {class: 'fp-label'}, 'SP'), meter('sp', loop.y, 'sp'),
        el('span', {class: 'fp-label'}, 'PV'), meter('pv', loop.y, 'pv'),
        el('span', {class: 'fp-label'}, 'OP'), meter('op', loop.u, 'op')));
    }
    const gains = Object.keys(p).filter((n) => GAIN.test(n.split('.').pop()) &&
      !n.startsWith('tuning.') && !Array.isArray(p[n].value)).sort();
    if (gains.length) {
      const row = el('div', {class: 'fp-gains', 'data-testid': 'gains'});
      for (const name of gains) {
        row.append(el('label', {title: p[name].description}, `${name} `,
                      paramInput(view, name, p[name], 'fp-input')));
      }
      box.append(row);
      box.append(...gains.map((name) => el('div', {class: 'reason', 'data-node': view.name, 'data-param': name})));
    }
    box.append(el('div', {class: 'reason', 'data-node': view.name, 'data-param': 'mode'}));
    box.append(el('div', {class: 'reason', 'data-node': view.name, 'data-param': 'manual_output'}));
    // the auto-tuner: its state topics and command buttons, or the tuning rule in use
    const tuner = el('div', {class: 'autotune', 'data-testid': `autotune-${view.name}`});
    const states = stateRows(view);
    if (view.commands.length || states.length) {
      tuner.append(el('b', {}, 'Auto-tuner '), ...states, commandButtons(view));
    } else {
      tuner.append(el('b', {}, 'Tuning '));
      if (p['tuning.rule']) {
        tuner.append('rule ', paramInput(view, 'tuning.rule', p['tuning.rule'], 'fp-input'),
                     el('span', {class: 'hint'}, ' (no relay auto-tuner on this controller)'));
      } else {
        tuner.append(el('span', {class: 'hint'}, 'no auto-tuner on this controller'));
      }
    }
    box.append(tuner);
    if (p['tuning.rule']) box.append(tuningView(view));
    if (old) old.replaceWith(box);
    else $('#faceplates').append(box);
    updateFaceplate(view, box);
  }

  function latest(topic, channel) {
    const buf = state.topics[topic];
    const col = buf?.ch[channel];
    if (!col) return null;
    for (let i = col.length - 1; i >= 0; i--) if (col[i] !== null && finite(num(col[i]))) return num(col[i]);
    return null;
  }

  // The scale of a bar: the limits when they are finite and near the value, else the span of
  // the channel's samples in the trend window.
  function scaleOf(limits, topics, channel) {
    if (limits) {
      const [lo, hi] = limits.map(num);
      if (finite(lo) && finite(hi) && hi > lo && hi - lo < 1e9) return {lo, hi, label: 'limits'};
    }
    let lo = Infinity; let hi = -Infinity;
    for (const topic of topics) {
      const buf = state.topics[topic];
      const col = buf?.ch[channel];
      if (!col) continue;
      const from = lowerBound(buf.t, buf.t[buf.t.length - 1] - state.windowS);
      for (let i = from; i < col.length; i++) {
        const v = num(col[i]);
        if (finite(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
      }
    }
    if (!(hi >= lo)) return null;
    const pad = Math.max(hi - lo, Math.abs(hi) * 0.1, 1e-9) * 0.1;
    return {lo: lo - pad, hi: hi + pad, label: 'trend'};
  }

  function setMeter(row, value, scale, mark = null) {
    if (!row) return;
    row.querySelector('.fp-value').textContent = value === null ? '–' : fmt(value);
    row.querySelector('.fp-unit').textContent = state.units[row.getAttribute('data-channel')] || '';
    const fill = row.querySelector('.fill');
    const bar = row.querySelector('.bar');
    const limits = row.querySelector('.bar-limits');
    if (!scale || value === null) { fill.style.width = '0'; limits.textContent = ''; return; }
    const frac = (v) => Math.min(1, Math.max(0, (v - scale.lo) / (scale.hi - scale.lo)));
    fill.style.width = `${(100 * frac(value)).toFixed(1)}%`;
    bar.classList.toggle('at-limit', scale.label === 'limits' &&
      (value <= scale.lo + 1e-9 * Math.abs(scale.lo) || value >= scale.hi - 1e-9 * Math.abs(scale.hi)));
    limits.textContent = `${fmt(scale.lo)} … ${fmt(scale.hi)}`;
    limits.title = scale.label === 'limits' ? 'the limits' : 'range of the trend window';
    const markEl = row.querySelector('.sp-mark');
    markEl.hidden = mark === null;
    if (mark !== null) markEl.style.left = `${(100 * frac(mark)).toFixed(1)}%`;
  }

  function reference() {
    return Object.values(state.nodes).find((v) => v.loaded && Object.keys(v.params).some((n) => n.startsWith('setpoint.')));
  }

  function updateFaceplate(view, box) {
    const ref = reference();
    for (const loop of loopsOf(view)) {
      const part = box.querySelector(`.loop[data-loop="${CSS.escape(loop.y)}"]`);
      if (!part) continue;
      const sp = latest('setpoint', loop.y);
      const pv = latest('measurement', loop.y);
      const op = latest('manipulated', loop.u);
      const spLimits = ref && ref.params[`setpoint.${loop.y}.min`] && ref.params[`setpoint.${loop.y}.max`]
        ? [ref.params[`setpoint.${loop.y}.min`].value, ref.params[`setpoint.${loop.y}.max`].value] : null;
      const yScale = scaleOf(spLimits, ['measurement', 'setpoint'], loop.y);
      setMeter(part.querySelector('[data-testid=sp]'), sp, yScale);
      setMeter(part.querySelector('[data-testid=pv]'), pv, yScale, sp);
      setMeter(part.querySelector('[data-testid=op]'), op, scaleOf(state.limits[loop.u] || null, ['manipulated'], loop.u));
    }
    showStatus(view, box.querySelector('[data-testid=status]'));
    window.tankLoops.show(box, view.diagnostics?.fields);   // the loop monitor's indices (loops.js)
  }

  function updateFaceplates() {
    for (const view of Object.values(state.nodes)) {
      const box = document.getElementById(faceplateId(view.name));
      if (box && isController(view)) updateFaceplate(view, box);
    }
  }

  // Alarms and fail-safe: the node's /diagnostics (level, message, fault, saturation).
  function showStatus(view, target) {
    if (!target) return;
    const d = view.diagnostics || {};
    const f = d.fields || {};
    const badges = [];
    const level = d.level ?? -1;
    badges.push([level === 0 ? 'OK' : level === 1 ? 'WARN' : level >= 2 ? 'ALARM' : 'no diagnostics yet',
                 level === 1 ? 'warn' : level >= 2 ? 'alarm' : '']);
    if (f.fault && f.fault !== 'none') badges.push([`fault: ${f.fault} → fail-safe (${view.params.fail_safe?.value ?? 'hold'})`, 'alarm']);
    if (f.saturated === 'True' || f.saturated === 'true') badges.push(['saturated', 'warn']);
    // the loop monitor's verdict per loop (docs/monitoring.md): loop_performance.<output>
    for (const [key, verdict] of Object.entries(f)) {
      if (key.startsWith('loop_performance.')) {
        badges.push([`loop ${key.slice(17)}: ${verdict}`, verdict === 'good' ? '' : 'warn']);
      }
    }
    if (view.params.fail_safe) badges.push([`fail-safe: ${view.params.fail_safe.value}`, '']);
    const text = `${badges.map((b) => b[0]).join(' · ')}${d.message ? ' — ' + d.message : ''}`;
    if (target.dataset.text === text) return;
    target.dataset.text = text;
    target.replaceChildren(...badges.map(([t, c]) => el('span', {class: `badge ${c}`}, t)));
    target.title = d.message || '';
    target.setAttribute('data-level', String(level));
  }

  // ---------------------------------------------------------------- tuning view
  // A rule and one of its settings (a slider), the predicted gains, margins and steps
  // (dashboard_node: robustness.tuning_preview) before anything is set; Apply sends them
  // (after a confirmation), Revert sets back the values from before the last Apply.
  state.tuning = {};       // node -> {open, rule, knob, value, result, before}

  function tuningOf(node) {
    if (!state.tuning[node]) state.tuning[node] = {open: false};
    return state.tuning[node];
  }

  function knobsOf(p) {
    return Object.keys(p).filter((n) => n.startsWith('tuning.') && p[n].type === 3 &&
                                 !p[n].read_only).sort();
  }

  function tuningView(view) {
    const p = view.params;
    const tv = tuningOf(view.name);
    if (tv.rule === undefined) tv.rule = String(p['tuning.rule'].value);
    const knobs = knobsOf(p);
    if (!knobs.includes(tv.knob)) tv.knob = knobs.includes('tuning.ms_target') ? 'tuning.ms_target' : knobs[0];
    if (tv.value === undefined && tv.knob) tv.value = num(p[tv.knob].value);
    const box = el('details', {class: 'tuning-view', 'data-testid': `tuning-${view.name}`});
    box.open = tv.open;
    box.addEventListener('toggle', () => { tv.open = box.open; });
    box.append(el('summary', {}, 'Tuning view: predict before applying'));
    const rule = el('select', {'data-tv': 'rule'});
    for (const c of choicesOf(p['tuning.rule']) || []) rule.append(el('option', {value: c}, c));
    rule.value = tv.rule;
    const knob = el('select', {'data-tv': 'knob'});
    for (const k of knobs) knob.append(el('option', {value: k}, k.slice('tuning.'.length)));
    if (tv.knob) knob.value = tv.knob;
    const value = el('input', {type: 'text', 'data-tv': 'value', value: fmt(tv.value ?? 0)});
    const slider = el('input', {type: 'range', min: 0, max: 100, step: 1, 'data-tv': 'slider'});
    const centre = num(p[tv.knob]?.value);
    // the slider: a factor 1/4 … 4 of the running value on a log scale (linear ±10 around 0)
    const toValue = (pos) => (centre > 0 ? centre * Math.pow(4, (pos - 50) / 50) : (pos - 50) / 5);
    const toPos = (v) => (centre > 0 && v > 0 ? 50 + 50 * Math.log(v / centre) / Math.log(4) : v * 5 + 50);
    slider.value = String(Math.round(toPos(tv.value ?? centre)));
    const preview = el('button', {type: 'button', 'data-tv': 'preview'}, 'Preview');
    const apply = el('button', {type: 'button', 'data-tv': 'apply', disabled: state.readOnly}, 'Apply');
    const revert = el('button', {type: 'button', 'data-tv': 'revert', disabled: state.readOnly || !tv.before},
                      'Revert');
    const result = el('div', {class: 'tv-result', 'data-tv': 'result'});
    const ask = () => {
      tv.rule = rule.value; tv.knob = knob.value; tv.value = parseFloat(value.value);
      tv.result = {pending: true};
      showPreview(view, result);
      askPreview(view.name);
    };
    rule.addEventListener('change', ask);
    knob.addEventListener('change', () => { tv.knob = knob.value; tv.value = num(p[tv.knob].value); renderFaceplate(view); });
    slider.addEventListener('input', () => { value.value = fmt(toValue(Number(slider.value))); });
    slider.addEventListener('change', ask);
    value.addEventListener('change', ask);
    preview.addEventListener('click', ask);
    apply.addEventListener('click', () => applyTuning(view));
    revert.addEventListener('click', () => revertTuning(view));
    box.append(el('div', {class: 'tv-controls'}, 'rule ', rule, ' setting ', knob, ' ', slider, value),
               el('div', {class: 'tv-controls'}, preview, apply, revert), result);
    showPreview(view, result);
    return box;
  }

  // The preview of the view's rule and setting, asked of dashboard_node.
  function askPreview(node) {
    const tv = tuningOf(node);
    const changes = {'tuning.rule': tv.rule};
    if (tv.knob && finite(tv.value)) changes[tv.knob] = String(tv.value);
    send({type: 'preview', node, changes, id: state.nextId++});
  }

  // A preview asked before dashboard_node knew the plant's (or the controller's) parameters
  // (``waiting``) is asked again once the robustness panel's analysis is available: the
  // loop's nodes are known now.
  function previewAgain(robustness) {
    state.loopKnown = Boolean(robustness && robustness.available);
    if (!state.loopKnown) return;
    for (const [node, tv] of Object.entries(state.tuning)) {
      if (tv.result && tv.result.waiting && state.nodes[node]) {
        tv.result = {pending: true};
        const target = document.querySelector(`#${faceplateId(node)} [data-tv=result]`);
        if (target) showPreview(state.nodes[node], target);
        askPreview(node);
      }
    }
  }

  function showPreview(view, target) {
    const r = tuningOf(view.name).result;
    if (!r) { target.replaceChildren(el('span', {class: 'hint'}, 'choose a rule and move the slider')); return; }
    if (r.pending) { target.replaceChildren(el('span', {class: 'hint'}, 'computing…')); return; }
    if (!r.available) {
      target.replaceChildren(el('span', {class: 'reason'},
                                r.waiting ? `${r.reason} (asked again when it is there)` : r.reason));
      return;
    }
    const g = r.gains; const m = r.margins;
    const line = (label, items) => el('div', {}, el('b', {}, label + ' '),
      ...items.map(([k, v, testid]) => el('span', {class: 'tv-num', 'data-testid': testid}, `${k} ${v}  `)));
    const parts = [
      line('gains', [['kp', fmt(g.kp), 'kp'], ['ti', fmt(g.ti), 'ti'], ['td', fmt(g.td), 'td'],
                     ['b', fmt(g.b), 'b'], ['c', fmt(g.c), 'c']]),
      line('margins', [['GM', fmt(m.gain_margin), 'gm'], ['PM', `${fmt(m.phase_margin)}°`, 'pm'],
                       ['Ms', fmt(m.ms), 'ms'], ['Mt', fmt(m.mt), 'mt'],
                       ['delay margin', `${fmt(m.delay_margin)} s`, 'dm']]),
    ];
    if (r.t) {
      parts.push(line('setpoint step', [['overshoot', `${fmt(r.overshoot)} %`, 'overshoot'],
                                        ['settling', `${fmt(r.settling_time)} s`, 'settling']]));
      const canvas = el('canvas', {width: 420, height: 110, class: 'tv-step'});
      parts.push(canvas);
      drawSteps(canvas, r);
    } else if (r.step_reason) parts.push(el('div', {class: 'hint'}, r.step_reason));
    target.replaceChildren(...parts);
  }

  // Unit setpoint step (blue) and unit load step (orange) of the prediction.
  function drawSteps(canvas, r) {
    const ctx = canvas.getContext('2d');
    const w = canvas.width; const h = canvas.height;
    const t1 = r.t[r.t.length - 1] || 1;
    const all = [...r.setpoint, ...r.load, 0, 1].map(num).filter(finite);
    const lo = Math.min(...all); const hi = Math.max(...all);
    const x = (t) => 4 + (w - 8) * t / t1;
    const y = (v) => h - 12 - (h - 20) * (v - lo) / ((hi - lo) || 1);
    ctx.clearRect(0, 0, w, h);
    ctx.strokeStyle = '#bbb'; ctx.setLineDash([3, 3]);
    for (const v of [0, 1]) { ctx.beginPath(); ctx.moveTo(x(0), y(v)); ctx.lineTo(x(t1), y(v)); ctx.stroke(); }
    ctx.setLineDash([]);
    for (const [series, color] of [[r.setpoint, '#1f77b4'], [r.load, '#ff7f0e']]) {
      ctx.strokeStyle = color; ctx.beginPath();
      series.forEach((v, i) => { const f = i ? 'lineTo' : 'moveTo'; ctx[f](x(r.t[i]), y(num(v))); });
      ctx.stroke();
    }
    ctx.fillStyle = '#555'; ctx.font = '10px sans-serif';
    ctx.fillText(`0 … ${fmt(t1)} s: setpoint step (blue), load step (orange)`, 6, h - 1);
  }

  function onPreviewResult(msg) {
    const view = state.nodes[msg.node];
    if (!view) return;
    const tv = tuningOf(msg.node);
    if (msg.waiting && state.loopKnown && !tv.askedAgain) {
      // answered "waiting" though the panel's analysis arrived first: ask once more
      tv.askedAgain = true;
      askPreview(msg.node);
      return;
    }
    tv.askedAgain = false;
    tv.result = msg;
    const target = document.querySelector(`#${faceplateId(msg.node)} [data-tv=result]`);
    if (target) showPreview(view, target);
  }

  // The changes of the tuning view that differ from the running values: the setting first, so
  // the rule (which derives the gains) comes last.
  function tuningChanges(view) {
    const tv = tuningOf(view.name);
    const p = view.params;
    const out = [];
    if (tv.knob && finite(tv.value) && num(p[tv.knob].value) !== tv.value) out.push([tv.knob, String(tv.value)]);
    if (String(p['tuning.rule'].value) !== tv.rule) out.push(['tuning.rule', tv.rule]);
    return out;
  }

  function applyTuning(view) {
    const changes = tuningChanges(view);
    if (!changes.length) return;
    const p = view.params;
    const text = changes.map(([n, v]) => `${n} ${formatValue(p[n].value)} → ${v}`).join(', ');
    confirming = {node: view.name, multi: changes, old: changes.map(([n]) => [n, formatValue(p[n].value)])};
    $('#confirm-text').textContent = `${view.name}: ${text}`;
    $('#confirm').hidden = false;
    $('#confirm-apply').focus();
  }

  function revertTuning(view) {
    const tv = tuningOf(view.name);
    if (!tv.before) return;
    for (const [n, v] of tv.before.slice().reverse()) submit(view.name, n, v, null);
    tv.before = null;
    renderFaceplate(view);
  }

  // ---------------------------------------------------------------- writes, confirm, undo
  const pending = {};      // request id -> {text, undo: {old} | null}
  let confirming = null;   // {node, name, text, old}

  function requestWrite(node, name, text) {
    const p = state.nodes[node]?.params[name];
    if (!p) return;
    const old = formatValue(p.value);
    if (!needsConfirm(node)) { submit(node, name, text, null); return; }
    if (text === old) { showValue(node, name); return; }
    confirming = {node, name, text, old};
    $('#confirm-text').textContent = `${node}: ${name} ${old} → ${text}`;
    $('#confirm').hidden = false;
    $('#confirm-apply').focus();
  }

  function closeConfirm(apply) {
    const c = confirming;
    confirming = null;
    $('#confirm').hidden = true;
    if (!c) return;
    if (c.multi) {                           // the tuning view's Apply
      if (!apply) return;
      for (const [n, v] of c.multi) submit(c.node, n, v, null);
      tuningOf(c.node).before = c.old;
      const view = state.nodes[c.node];
      if (view) renderFaceplate(view);
      return;
    }
    if (apply) submit(c.node, c.name, c.text, {old: c.old});
    else showValue(c.node, c.name);          // cancelled: the field shows the running value
  }
  $('#confirm-apply').addEventListener('click', () => closeConfirm(true));
  $('#confirm-cancel').addEventListener('click', () => closeConfirm(false));
  document.addEventListener('keydown', (ev) => { if (ev.key === 'Escape' && confirming) closeConfirm(false); });

  let undoable = null;     // {node, name, old, text}
  function offerUndo(node, name, old, text) {
    undoable = {node, name, old, text};
    $('#undo-text').textContent = `${node}: ${name} ${old} → ${text} applied`;
    $('#undo-button').hidden = false;
    $('#undo').hidden = false;
  }
  $('#undo-button').addEventListener('click', () => {
    const u = undoable;
    if (!u) return;
    undoable = null;
    submit(u.node, u.name, u.old, null);
    $('#undo-text').textContent = `${u.node}: ${u.name} back to ${u.old}…`;
    $('#undo-button').hidden = true;
  });
  $('#undo-close').addEventListener('click', () => { undoable = null; $('#undo').hidden = true; });

  function submit(node, name, text, undo) {
    const id = state.nextId++;
    pending[id] = {text, undo};
    for (const input of findAll(node, name)) input.classList.add('pending');
    send({type: 'set', node, name, text, id});
  }

  function findAll(node, name, kind = ':is(input, select)') {
    return document.querySelectorAll(`${kind}[data-node="${CSS.escape(node)}"][data-param="${CSS.escape(name)}"]`);
  }

  function find(kind, node, name) {
    return document.querySelector(`${kind}[data-node="${CSS.escape(node)}"][data-param="${CSS.escape(name)}"]`);
  }

  function showValue(node, name) {
    const p = state.nodes[node]?.params[name];
    if (!p) return;
    for (const input of findAll(node, name)) {
      if (input.type === 'checkbox') input.checked = p.value === true;
      else if (input.tagName === 'SELECT') input.value = String(p.value);
      else if (document.activeElement !== input) input.value = formatValue(p.value);
    }
  }

  function onParam(msg) {
    const view = state.nodes[msg.node];
    const p = view?.params[msg.name];
    if (!p) return;
    p.value = msg.value;
    p.type = msg.ptype;
    showValue(msg.node, msg.name);
    const row = find('tr', msg.node, msg.name);
    if (row) { row.classList.remove('changed'); void row.offsetWidth; row.classList.add('changed'); }
    if (isController(view) && (msg.name === 'mode' || msg.name === 'fail_safe' ||
                               msg.name.endsWith('_names'))) renderFaceplate(view);
  }

  function onSetResult(msg) {
    const sent = pending[msg.id];
    delete pending[msg.id];
    const typed = sent?.text;
    for (const input of findAll(msg.node, msg.name)) input.classList.remove('pending');
    const reasons = findAll(msg.node, msg.name, 'div.reason');
    if (msg.successful) {
      for (const reason of reasons) { reason.textContent = ''; reason.className = 'reason ok'; }
      if (sent?.undo) offerUndo(msg.node, msg.name, sent.undo.old, typed);
      else if (!$('#undo').hidden && $('#undo-button').hidden) {
        $('#undo-text').textContent = `${msg.node}: ${msg.name} back to ${typed}`;
      }
    } else {
      const why = msg.reason.startsWith('refused:') ? msg.reason : `refused: ${msg.reason}`;
      for (const reason of reasons) {
        reason.textContent = `${typed !== undefined ? `"${typed}" ` : ''}${why}`;
        reason.className = 'reason refused';
      }
      for (const input of findAll(msg.node, msg.name)) input.blur();
      showValue(msg.node, msg.name);
    }
  }

  function onCommandResult(msg) {
    const out = document.querySelector(`.command-result[data-node="${CSS.escape(msg.node)}"][data-command="${CSS.escape(msg.command)}"]`);
    if (out) {
      out.textContent = `${msg.success ? 'ok' : 'failed'}: ${msg.message}`;
      out.classList.toggle('reason', !msg.success);
    }
  }

  function onState(msg) {
    const view = state.nodes[msg.node];
    if (!view) return;
    const known = msg.topic in view.states;
    view.states[msg.topic] = msg.value;
    const out = document.querySelector(`.state[data-node="${CSS.escape(msg.node)}"][data-topic="${CSS.escape(msg.topic)}"]`);
    if (out) out.textContent = msg.value;
    else if (!known) setNode(view);
  }

  function showDiagnostics(target, info) {
    target.textContent = info.message;
    target.className = `diag level-${info.level}`;
  }

  function onDiagnostics(msg) {
    const view = state.nodes[msg.node];
    if (view) view.diagnostics = {level: msg.level, message: msg.message, fields: msg.fields || {}};
    const target = document.querySelector(`.diag[data-node="${CSS.escape(msg.node)}"]`);
    if (target) showDiagnostics(target, msg);
  }

  // ---------------------------------------------------------------- audit trail
  // Every parameter change a node applied (/parameter_audit, nodes/params.py), newest first.
  const AUDIT_SHOWN = 200;
  state.audit = [];
  function onAudit(record) {
    state.audit.push(record);
    if (state.audit.length > AUDIT_SHOWN) state.audit.shift();
    $('#no-audit')?.remove();
    const when = new Date(record.time * 1000);
    const row = el('tr', {'data-node': String(record.node), 'data-param': String(record.name)},
      el('td', {title: when.toISOString()}, when.toLocaleTimeString()),
      el('td', {}, String(record.node)), el('td', {}, String(record.name)),
      el('td', {class: 'audit-change'}, `${formatValue(record.old)} → ${formatValue(record.new)}`),
      el('td', {class: 'audit-source'}, String(record.source)));
    const rows = $('#audit-rows');
    rows.prepend(row);
    while (rows.children.length > AUDIT_SHOWN) rows.lastChild.remove();
  }

  connect();
})();
