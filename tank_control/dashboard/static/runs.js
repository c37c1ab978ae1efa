// tank_control dashboard: the runs page. Lists the run folders under dashboard_node's
// runs_dir (GET /api/runs, tank_control/dashboard/runs.py) with their scenario, title,
// complete flag and key metrics, links to their pictures, and compares the selected runs'
// metrics side by side.
'use strict';

window.tankRuns = (() => {
  const KEY_METRICS = ['iae', 'overshoot_pct', 'settling_time', 'loop.stable', 'loop.gain_margin',
                       'loop.phase_margin', 'loop.ms'];
  const state = {table: null, selected: new Set(), loads: 0};
  const $ = (sel) => document.querySelector(sel);
  const el = (tag, attrs = {}, ...children) => {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k.startsWith('data-')) e.setAttribute(k, v); else e[k] = v;
    }
    for (const c of children) e.append(c);
    return e;
  };
  const fileUrl = (run, file) => '/runs/file/' + run.split('/').map(encodeURIComponent).join('/')
    + '/' + encodeURIComponent(file);
  const show = (v) => {
    if (v === null || v === undefined) return '–';
    if (v === true) return 'yes';
    if (v === false) return 'no';
    if (v === 'inf') return '∞';
    if (v === '-inf') return '−∞';
    if (v === 'nan') return '–';
    if (typeof v === 'number') return Number(v.toPrecision(4)).toString();
    return String(v);
  };
  // the key metrics of a run: the first output's IAE / worst step and the loop's robustness
  function keyMetrics(run) {
    const out = {};
    for (const key of KEY_METRICS) {
      const name = Object.keys(run.metrics).find((k) => k === key || k.endsWith('.' + key));
      if (name !== undefined) out[name] = run.metrics[name];
    }
    return out;
  }

  function render(table) {
    state.table = table;
    $('#runs-dir').textContent = table.runs_dir ? `runs_dir ${table.runs_dir}` : '';
    $('#runs-hint').textContent = table.hint;
    const t = $('#runs');
    t.replaceChildren();
    if (!table.runs.length) return;
    const head = t.insertRow();
    for (const title of ['', 'run', 'scenario', 'title', 'complete', 'key metrics', 'pictures']) {
      head.append(el('th', {textContent: title}));
    }
    for (const run of table.runs) {
      const row = t.insertRow();
      row.dataset.run = run.name;
      const box = el('input', {type: 'checkbox', checked: state.selected.has(run.name)});
      box.dataset.run = run.name;
      box.addEventListener('change', () => {
        if (box.checked) state.selected.add(run.name); else state.selected.delete(run.name);
        $('#compare').disabled = state.selected.size < 2;
      });
      row.insertCell().append(box);
      row.insertCell().textContent = run.name;
      row.insertCell().textContent = run.scenario;
      row.insertCell().textContent = run.title;
      const complete = row.insertCell();
      complete.className = 'complete';
      complete.textContent = run.complete === true ? 'yes'
        : run.complete === false ? `no: ${run.reason}` : '–';
      const metrics = row.insertCell();
      metrics.className = 'metrics';
      if (run.error) metrics.append(el('span', {className: 'reason', textContent: run.error}));
      for (const [k, v] of Object.entries(keyMetrics(run))) {
        metrics.append(el('span', {className: 'metric', textContent: `${k} ${show(v)}`,
                                   'data-metric': k}), ' ');
      }
      for (const [loop, verdict] of Object.entries(run.verdicts || {})) {   // docs/monitoring.md
        metrics.append(el('span', {className: 'verdict', textContent: `${loop}: ${verdict}`,
                                   'data-loop': loop}), ' ');
      }
      const pics = row.insertCell();
      for (const file of run.files) {
        pics.append(el('a', {href: fileUrl(run.name, file), textContent: file, target: '_blank',
                             className: 'picture'}), ' ');
      }
    }
    $('#compare').disabled = state.selected.size < 2;
  }

  function compare() {
    const runs = state.table.runs.filter((r) => state.selected.has(r.name));
    const t = $('#compare-table');
    t.replaceChildren();
    const head = t.insertRow();
    head.append(el('th', {textContent: 'metric'}));
    for (const run of runs) head.append(el('th', {textContent: run.name}));
    const rows = [['scenario', (r) => r.scenario], ['title', (r) => r.title],
                  ['complete', (r) => r.complete]];
    const keys = [];
    for (const run of runs) for (const k of Object.keys(run.metrics)) if (!keys.includes(k)) keys.push(k);
    for (const k of keys) rows.push([k, (r) => r.metrics[k]]);
    for (const [name, get] of rows) {
      const row = t.insertRow();
      row.dataset.metric = name;
      row.insertCell().textContent = name;
      for (const run of runs) {
        const cell = row.insertCell();
        cell.dataset.run = run.name;
        cell.textContent = show(get(run));
      }
    }
    $('#comparison').hidden = false;
  }

  async function load() {
    try {
      const response = await fetch('/api/runs', {cache: 'no-store'});
      render(await response.json());
    } catch (err) {
      $('#runs-hint').textContent = `runs not read: ${err}`;
    }
    state.loads += 1;
    document.body.dataset.loads = String(state.loads);
  }

  $('#reload').addEventListener('click', load);
  $('#compare').addEventListener('click', compare);
  load();
  return {state, load};
})();
