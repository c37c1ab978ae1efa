// tank_control dashboard page: trends of the signal topics (uPlot), a parameter panel per
// node, the controller's commands and state topics. One WebSocket (/ws) to dashboard_node;
// the messages are described in tank_control/dashboard/server.py. Times: s of plant time.
'use strict';

(() => {
  const KEEP_S = 3600;            // history kept in the page [s of plant time]
  const NODE_ORDER = ['/plant', '/controller', '/reference'];
  const COLORS = ['#1f77b4', '#d62728', '#2ca02c', '#9467bd', '#ff7f0e', '#8c564b',
                  '#e377c2', '#17becf'];

  const state = {
    paused: false,
    windowS: 30,
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
        for (const name of Object.keys(state.nodes)) removeNode(name);
        for (const view of Object.values(msg.nodes)) setNode(view);
        refreshLimits();
        if (msg.robustness) window.tankRobustness.update(msg.robustness);
        if (msg.missed) onMissed(msg.missed);
        state.marks = (msg.marks || []).slice();
        state.audit = [];
        $('#audit-rows').replaceChildren();
        for (const record of msg.audit || []) onAudit(record);
        state.serverReadOnly = !!msg.read_only;
        showAccess(state.serverReadOnly);
        break;
      case 'robustness': window.tankRobustness.update(msg); break;
      case 'missed': onMissed(msg.missed); break;
      case 'mark': onMark(msg); break;
      case 'samples': onSamples(msg); break;
      case 'node': setNode(msg.node); break;
      case 'node_gone': removeNode(msg.node); break;
      case 'param': onParam(msg); break;
      case 'state': onState(msg); break;
      case 'diagnostics': onDiagnostics(msg); break;
      case 'limits': state.limits = msg.limits; refreshLimits(); break;
      case 'set_result': onSetResult(msg); break;
      case 'command_result': onCommandResult(msg); break;
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
  function chartFor(id, title) {
    let chart = state.charts[id];
    if (chart) return chart;
    const body = el('div', {class: 'plot'});
    const box = el('div', {class: 'chart', id: 'chart-' + id, 'data-chart': id,
                           'data-points': '0'}, el('h3', {}, title), body);
    $('#no-data')?.remove();
    const order = ['y-', 'u-', 'd'];
    const rank = (k) => order.findIndex((p) => k.startsWith(p));
    const later = Object.keys(state.charts).filter((k) => rank(k) > rank(id) ||
      (rank(k) === rank(id) && k > id)).sort((a, b) => rank(a) - rank(b) || (a < b ? -1 : 1));
    const before = later.length ? state.charts[later[0]].el : null;
    $('#trends').insertBefore(box, before);
    chart = state.charts[id] = {el: box, body, plot: null, title, sources: [], limits: null};
    return chart;
  }

  function addChannel(topic, name) {
    let chart;
    if (topic === 'measurement') chart = chartFor('y-' + name, `output ${name}`);
    else if (topic === 'setpoint') chart = chartFor('y-' + name, `output ${name}`);
    else if (topic === 'manipulated') chart = chartFor('u-' + name, `input ${name}`);
    else chart = chartFor('d', 'disturbances');
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
    const opts = {width, height: 200, series,
                  scales: {x: {time: false}, y: {range: (u) => yRange(chart, u)}},
                  axes: [{}, {size: 70}],
                  legend: {live: true}, cursor: {drag: {x: true, y: false}},
                  hooks: {draw: [drawMarks]}};
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

  // Union of the sources' times inside the window, each series null where it has no sample.
  function windowData(chart, tEnd) {
    const tStart = tEnd - state.windowS;
    const parts = chart.sources.map((s) => {
      const buf = state.topics[s.topic];
      if (!buf) return {t: [], v: [], i: 0, end: 0};
      const i = lowerBound(buf.t, tStart);
      return {t: buf.t, v: buf.ch[s.channel] || [], i, end: buf.t.length};
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
      if (chart.plot) chart.plot.setSize({width: Math.max(300, chart.body.clientWidth), height: 200});
    }
  });

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
      state.dirty = true;
      schedule();
    }
  });

  // ---------------------------------------------------------------- nodes
  function nodeRank(name) {
    const i = NODE_ORDER.indexOf(name);
    return i < 0 ? NODE_ORDER.length : i;
  }

  function formatValue(v) {
    if (Array.isArray(v)) return JSON.stringify(v);
    return String(v);
  }

  function rangeText(p) {
    const parts = [];
    if (p.range) {
      const [lo, hi] = p.range.map(num);
      parts.push(`[${finite(lo) ? lo : '−∞'}, ${finite(hi) ? hi : '∞'}]`);
    }
    if (p.read_only) parts.push('read-only');
    return parts.join(' ');
  }

  function setNode(view) {
    state.nodes[view.name] = view;
    $('#no-nodes')?.remove();
    const id = 'node-' + view.name.replace(/[^A-Za-z0-9_-]/g, '_');
    const box = el('div', {class: 'node', id, 'data-node': view.name});
    const diag = el('span', {class: 'diag', 'data-node': view.name});
    box.append(el('h2', {}, view.name, diag));
    if (view.diagnostics && view.diagnostics.message !== undefined) showDiagnostics(diag, view.diagnostics);
    if (view.commands.length) {
      const cmds = el('div', {class: 'commands'});
      for (const command of view.commands) {
        const button = el('button', {type: 'button', 'data-node': view.name, 'data-command': command,
                                     disabled: state.readOnly},
                          command.replace(/_/g, ' '));
        button.addEventListener('click', () => {
          result.textContent = '…';
          send({type: 'command', node: view.name, command, id: state.nextId++});
        });
        const result = el('span', {class: 'command-result', 'data-node': view.name, 'data-command': command});
        cmds.append(el('div', {}, button, result));
      }
      box.append(cmds);
    }
    for (const [topic, value] of Object.entries(view.states || {})) {
      box.append(el('div', {class: 'state-row'}, `${topic}: `,
                    el('b', {class: 'state', 'data-node': view.name, 'data-topic': topic}, value)));
    }
    if (!view.loaded) {
      box.append(el('p', {class: 'hint'}, 'reading parameters…'));
    } else {
      const table = el('table', {class: 'params'});
      for (const name of Object.keys(view.params).sort()) {
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

  function removeNode(name) {
    delete state.nodes[name];
    document.querySelector(`#nodes .node[data-node="${CSS.escape(name)}"]`)?.remove();
  }

  function paramRow(view, name, p) {
    const attrs = {'data-node': view.name, 'data-param': name};
    let input;
    if (p.type === 1) {
      input = el('input', {type: 'checkbox', checked: p.value === true, disabled: p.read_only || state.readOnly, ...attrs});
      input.addEventListener('change', () => submit(input, input.checked ? 'true' : 'false'));
    } else {
      input = el('input', {type: 'text', value: formatValue(p.value), disabled: p.read_only || state.readOnly,
                           spellcheck: false, ...attrs});
      input.addEventListener('change', () => submit(input, input.value));
      input.addEventListener('keydown', (ev) => {
        if (ev.key === 'Escape') { input.value = formatValue(state.nodes[view.name].params[name].value); input.blur(); }
      });
    }
    const reason = el('div', {class: 'reason', ...attrs});
    const tr = el('tr', {...attrs},
      el('td', {class: 'name', title: p.description}, name, el('div', {class: 'desc'}, p.description)),
      el('td', {}, input, reason),
      el('td', {class: 'range', title: p.constraints || ''}, rangeText(p)));
    return tr;
  }

  const pending = {};      // request id -> typed text
  function submit(input, text) {
    const id = state.nextId++;
    pending[id] = text;
    input.classList.add('pending');
    const node = input.getAttribute('data-node');
    const name = input.getAttribute('data-param');
    send({type: 'set', node, name, text, id});
  }

  function find(kind, node, name) {
    return document.querySelector(`${kind}[data-node="${CSS.escape(node)}"][data-param="${CSS.escape(name)}"]`);
  }

  function showValue(node, name) {
    const p = state.nodes[node]?.params[name];
    const input = find('input', node, name);
    if (!p || !input) return;
    if (input.type === 'checkbox') input.checked = p.value === true;
    else if (document.activeElement !== input) input.value = formatValue(p.value);
  }

  function onParam(msg) {
    const p = state.nodes[msg.node]?.params[msg.name];
    if (!p) return;
    p.value = msg.value;
    p.type = msg.ptype;
    showValue(msg.node, msg.name);
    const row = find('tr', msg.node, msg.name);
    if (row) { row.classList.remove('changed'); void row.offsetWidth; row.classList.add('changed'); }
  }

  function onSetResult(msg) {
    const typed = pending[msg.id];
    delete pending[msg.id];
    const input = find('input', msg.node, msg.name);
    const reason = find('div.reason', msg.node, msg.name);
    if (input) input.classList.remove('pending');
    if (!reason) return;
    if (msg.successful) {
      reason.textContent = '';
      reason.className = 'reason ok';
    } else {
      const why = msg.reason.startsWith('refused:') ? msg.reason : `refused: ${msg.reason}`;
      reason.textContent = `${typed !== undefined ? `"${typed}" ` : ''}${why}`;
      reason.className = 'reason refused';
      if (input) { input.blur(); showValue(msg.node, msg.name); }
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
    if (view) view.diagnostics = {level: msg.level, message: msg.message};
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
