// tank_control dashboard: the robustness panel. Draws the `robustness` message of
// dashboard_node (tank_control/dashboard/robustness.py): Bode of the loop gain L = C·G
// (uPlot, log frequency axis), Nyquist of L (a canvas: the curve, −1 and the Ms circle) and
// the margins per model. Frequencies in rad/s, phase in degrees, delay margin in s.
'use strict';

window.tankRobustness = (() => {
  const COLORS = ['#1f77b4', '#d62728', '#2ca02c', '#9467bd'];
  const NYQ = {x: [-3, 1.5], y: [-2.5, 2]};          // the view of analysis.png
  const state = {msg: null, bode: {}, updates: 0};

  const $ = (sel) => document.querySelector(sel);
  const num = (v) => (v === 'inf' ? Infinity : v === '-inf' ? -Infinity : v === 'nan' ? NaN : v);
  const fmt = (v, digits, fixed) => {
    v = num(v);
    if (v === true) return 'yes';
    if (v === false) return 'NO';
    if (typeof v !== 'number' || Number.isNaN(v)) return '–';
    if (!Number.isFinite(v)) return v > 0 ? '∞' : '−∞';
    return fixed ? v.toFixed(digits) : Number(v.toPrecision(digits)).toString();
  };
  const COLUMNS = [['stable', 'stable'], ['gain_margin', 'GM'], ['phase_margin', 'PM [deg]'],
                   ['ms', 'Ms'], ['mt', 'Mt'], ['delay_margin', 'delay margin [s]'],
                   ['wc', 'ωc [rad/s]'], ['w180', 'ω180 [rad/s]']];

  function table(msg) {
    const t = document.createElement('table');
    t.className = 'margins';
    const head = t.insertRow();
    for (const title of ['model', ...COLUMNS.map((c) => c[1])]) {
      const th = document.createElement('th');
      th.textContent = title;
      head.append(th);
    }
    msg.cases.forEach((c, i) => {
      const row = t.insertRow();
      const label = row.insertCell();
      label.textContent = c.label;
      label.style.color = COLORS[i % COLORS.length];
      for (const [key] of COLUMNS) {
        const cell = row.insertCell();
        cell.className = 'margin';
        cell.dataset.case = String(i);
        cell.dataset.margin = key;
        cell.textContent = key === 'phase_margin' ? fmt(c.margins[key], 1, true)
          : fmt(c.margins[key], 3, false);
      }
    });
    return t;
  }

  function bodeChart(id, title, data, cases, yLog, guide) {
    const box = $(`#${id}`);
    const width = Math.max(box.clientWidth - 10, 300);
    const series = [{label: 'ω [rad/s]', value: (u, v) => (v == null ? '–' : v.toPrecision(4))}];
    cases.forEach((c, i) => series.push({label: c.label, stroke: COLORS[i % COLORS.length],
                                         width: 1.5, points: {show: false}}));
    series.push({label: guide.label, stroke: '#888', dash: [4, 4], width: 1,
                 points: {show: false}});
    const opts = {
      width, height: 200, title,
      // phase: −540…0°, as analysis.png (the dead time's phase falls without end)
      scales: {x: {time: false, distr: 3, log: 10},
               y: yLog ? {distr: 3, log: 10} : {range: [-540, 0]}},
      axes: [{label: 'ω [rad/s]'}, {size: 70}],
      legend: {show: true}, cursor: {drag: {x: false, y: false}},
      series,
    };
    if (state.bode[id]) state.bode[id].destroy();
    box.replaceChildren();
    state.bode[id] = new uPlot(opts, data, box);
    box.dataset.points = String(data[0].length);
  }

  function nyquist(msg) {
    const canvas = $('#nyquist');
    const ctx = canvas.getContext('2d');
    const w = canvas.width;
    const h = canvas.height;
    const sx = (x) => ((x - NYQ.x[0]) / (NYQ.x[1] - NYQ.x[0])) * w;
    const sy = (y) => h - ((y - NYQ.y[0]) / (NYQ.y[1] - NYQ.y[0])) * h;
    ctx.clearRect(0, 0, w, h);
    ctx.strokeStyle = '#ddd';
    ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.moveTo(sx(NYQ.x[0]), sy(0)); ctx.lineTo(sx(NYQ.x[1]), sy(0));
    ctx.moveTo(sx(0), sy(NYQ.y[0])); ctx.lineTo(sx(0), sy(NYQ.y[1]));
    ctx.stroke();
    ctx.fillStyle = '#666';
    ctx.font = '11px system-ui, sans-serif';
    for (let x = Math.ceil(NYQ.x[0]); x <= NYQ.x[1]; x += 1) ctx.fillText(String(x), sx(x) + 2, sy(0) - 2);
    for (let y = Math.ceil(NYQ.y[0]); y <= NYQ.y[1]; y += 1) if (y) ctx.fillText(String(y), sx(0) + 2, sy(y) - 2);
    ctx.fillText('Re L', w - 30, sy(0) + 12);
    ctx.fillText('Im L', sx(0) + 4, 12);
    msg.cases.forEach((c, i) => {
      const color = COLORS[i % COLORS.length];
      ctx.strokeStyle = color;
      ctx.lineWidth = 1.5;
      ctx.setLineDash([]);
      ctx.beginPath();
      let pen = false;
      for (let k = 0; k < c.re.length; k += 1) {
        const x = num(c.re[k]);
        const y = num(c.im[k]);
        if (!Number.isFinite(x) || !Number.isFinite(y) || Math.abs(x) > 1e6 || Math.abs(y) > 1e6) {
          pen = false;
          continue;
        }
        if (pen) ctx.lineTo(sx(x), sy(y)); else ctx.moveTo(sx(x), sy(y));
        pen = true;
      }
      ctx.stroke();
      const ms = num(c.margins.ms);
      if (Number.isFinite(ms) && ms > 0) {            // the Ms circle: centre −1, radius 1/Ms
        ctx.setLineDash([4, 3]);
        ctx.lineWidth = 0.8;
        ctx.beginPath();
        ctx.ellipse(sx(-1), sy(0), (sx(1 / ms) - sx(0)), (sy(0) - sy(1 / ms)), 0, 0, 2 * Math.PI);
        ctx.stroke();
      }
    });
    ctx.setLineDash([]);
    ctx.strokeStyle = '#000';
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    ctx.moveTo(sx(-1) - 6, sy(0)); ctx.lineTo(sx(-1) + 6, sy(0));
    ctx.moveTo(sx(-1), sy(0) - 6); ctx.lineTo(sx(-1), sy(0) + 6);
    ctx.stroke();
    canvas.dataset.cases = String(msg.cases.length);
  }

  function update(msg) {
    state.msg = msg;
    state.updates += 1;
    const panel = $('#robustness');
    if (!panel) return;
    panel.dataset.updates = String(state.updates);
    panel.dataset.available = String(Boolean(msg.available));
    $('#robustness-reason').textContent = msg.available ? '' : msg.reason;
    const body = $('#robustness-body');
    body.hidden = !msg.available;
    if (!msg.available) return;
    $('#robustness-pid').textContent = msg.controller;
    $('#margins').replaceChildren(table(msg));
    const w = msg.w.map(num);
    const ones = w.map(() => 1);
    const m180 = w.map(() => -180);
    bodeChart('bode-mag', '|L(jω)|', [w, ...msg.cases.map((c) => c.mag.map(num)), ones],
              msg.cases, true, {label: '|L| = 1'});
    bodeChart('bode-phase', 'phase of L [deg]',
              [w, ...msg.cases.map((c) => c.phase.map(num)), m180], msg.cases, false,
              {label: '−180°'});
    nyquist(msg);
  }

  return {update, state};
})();
