/* neckstrength app: the pages call the same JSON API as any client (docs/app.md). No external scripts. */
"use strict";
var NS = (function () {
  var TOKEN = document.querySelector('meta[name="neckstrength-token"]').content;

  function api(method, path, body) {
    var opt = {method: method, headers: {"X-Neckstrength-Token": TOKEN}};
    if (body !== undefined) { opt.headers["Content-Type"] = "application/json"; opt.body = JSON.stringify(body); }
    return fetch(path, opt).then(function (r) {
      return r.json().catch(function () { return {}; }).then(function (j) {
        if (!r.ok) {
          var d = (j && j.detail && j.detail[0]) || {};
          var field = (d.loc || []).slice(-1)[0];
          var err = new Error((field ? field + ": " : "") + (d.msg || ("HTTP " + r.status)));
          err.status = r.status; err.field = field; throw err;
        }
        return j;
      });
    });
  }
  function $(id) { return document.getElementById(id); }
  function esc(s) { return String(s == null ? "" : s).replace(/[&<>"']/g, function (c) {
    return {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c]; }); }
  function fmt(x, nd) { return (x == null || !isFinite(x)) ? "–" : Number(x).toFixed(nd || 0); }
  function svg(w, h, inner, cls) {
    return '<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 ' + w + ' ' + h + '" class="' + (cls || "") + '">' + inner + '</svg>';
  }

  /* ---- start page ---- */
  function startPage() {
    var f = $("create"), offer = JSON.parse($("emg-offer").textContent);
    function emgOptions() {     // the EMG channels the chosen model offers (surface, deep), as checkboxes
      var o = offer[f.elements.model.value] || {surface: [], deep: []};
      var grp = function (title, names) {
        return names.length ? '<div class="emg-group"><b>' + title + '</b>' + names.map(function (m) {
          return '<label class="inline"><input type="checkbox" name="emg_channel" value="' + esc(m) + '"> ' + esc(m) + '</label>'; }).join("") + '</div>' : ""; };
      $("emg-options").innerHTML = (grp("surface EMG (Appendix A.1)", o.surface) + grp("deep extensors, fine-wire EMG", o.deep)) ||
        '<p class="hint">This model offers no EMG channel.</p>';
    }
    f.elements.model.addEventListener("change", emgOptions);
    emgOptions();
    f.addEventListener("submit", function (ev) {
      ev.preventDefault();
      var body = {emg_channels: []}, fd = new FormData(f);
      fd.forEach(function (v, k) {
        v = String(v).trim();
        if (v === "") return;
        if (k === "emg_channel") { body.emg_channels.push(v); return; }
        body[k] = ["prevalence", "noise"].indexOf(k) >= 0 ? Number(v) :
                  ["n_candidates", "seed"].indexOf(k) >= 0 ? parseInt(v, 10) : v;
      });
      $("create-error").textContent = ""; $("create-busy").hidden = false; $("create-btn").disabled = true;
      api("POST", "/api/sessions", body).then(function () {
        location.href = "/s/" + encodeURIComponent(body.name);
      }).catch(function (e) {
        $("create-error").textContent = e.message; $("create-busy").hidden = true; $("create-btn").disabled = false;
      });
    });
  }

  /* ---- the head, front / side / top, with the test point and the push direction ---- */
  function headViews(geo, dir) {
    var g = geo[dir]; if (!g) return "";
    // skull frame: x forward, y up, z to the right; each view maps a vector to screen (right, down)
    var C = [0.01, 0.03, 0], S = 420;
    var views = [
      ["front", function (q) { return [-q[2], -q[1], q[0]]; }, 32, 50],   // facing the person: their right on our left
      ["side (right)", function (q) { return [q[0], -q[1], q[2]]; }, 42, 50],
      ["top", function (q) { return [q[2], -q[0], q[1]]; }, 32, 42]];     // from above, the nose up; [2]: towards us
    var defs = '<defs><marker id="arrow" viewBox="0 0 10 10" refX="8" refY="5" markerWidth="5" markerHeight="5" orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" class="arrowhead"/></marker></defs>';
    var out = "";
    views.forEach(function (v) {
      var cx = 65, cy = 70, f = v[1];
      var body = '<ellipse cx="' + cx + '" cy="' + cy + '" rx="' + v[2] + '" ry="' + v[3] + '" class="skull"/>';
      var nose = f([0.105, 0.0, 0]), eyeR = f([0.09, 0.045, 0.03]), eyeL = f([0.09, 0.045, -0.03]);
      [eyeR, eyeL].forEach(function (e, i) {
        if (v[0] !== "top" && !(v[0] === "side (right)" && i === 1)) body += '<circle cx="' + (cx + S * (e[0] - f(C)[0])).toFixed(1) + '" cy="' + (cy + S * (e[1] - f(C)[1])).toFixed(1) + '" r="3" class="eye"/>';
      });
      body += '<circle cx="' + (cx + S * (nose[0] - f(C)[0])).toFixed(1) + '" cy="' + (cy + S * (nose[1] - f(C)[1])).toFixed(1) + '" r="4" class="nose"/>';
      var p = f(g.point), n = f(g.normal), c0 = f(C);
      var px = cx + S * (p[0] - c0[0]), py = cy + S * (p[1] - c0[1]);
      var L = Math.sqrt(n[0] * n[0] + n[1] * n[1]);
      body += '<circle cx="' + px.toFixed(1) + '" cy="' + py.toFixed(1) + '" r="5" class="pad' + (p[2] - c0[2] < -0.02 ? ' far' : '') + '"/>';
      if (L > 0.3) body += '<line x1="' + px.toFixed(1) + '" y1="' + py.toFixed(1) + '" x2="' + (px + 34 * n[0]).toFixed(1) + '" y2="' + (py + 34 * n[1]).toFixed(1) + '" class="push" marker-end="url(#arrow)"/>';
      else body += '<circle cx="' + px.toFixed(1) + '" cy="' + py.toFixed(1) + '" r="10" class="push-depth"/>';
      out += '<figure>' + svg(130, 140, defs + body, "headview") + '<figcaption>' + v[0] + '</figcaption></figure>';
    });
    return out + '<p class="hint">dot: where the pad sits; arrow: the way the head pushes against the pad (the clinician resists); a hollow dot: the pad is on the far side of the head in that view; a dashed ring: the push is mostly towards or away from the viewer.</p>';
  }

  function bars(alts) {
    var top = Math.max.apply(null, alts.map(function (a) { return a.gain || 0; }).concat([1e-9]));
    return alts.slice(0, 12).map(function (a) {
      var w = Math.max(0, a.gain || 0) / top * 100;
      return '<div class="bar' + (a.proposed ? " proposed" : "") + (a.skipped ? " skipped" : "") + '"><span class="bl">' + esc(a.test) +
        '</span><span class="bt"><span style="width:' + w.toFixed(1) + '%"></span></span><span class="bv">' + fmt(a.gain, 3) + '</span></div>';
    }).join("") + (alts.length > 12 ? '<p class="hint">' + (alts.length - 12) + ' more tests with less information</p>' : "");
  }

  function trend(ps) {
    if (!ps || ps.length < 1) return "";
    var w = 220, h = 60, n = Math.max(ps.length - 1, 1);
    var pts = ps.map(function (p, i) { return (10 + i / n * (w - 20)).toFixed(1) + "," + (h - 8 - p * (h - 16)).toFixed(1); });
    return svg(w, h, '<line x1="10" x2="' + (w - 10) + '" y1="' + (h / 2) + '" y2="' + (h / 2) + '" class="mid"/>' +
      '<polyline points="' + pts.join(" ") + '" class="trend"/>' + pts.map(function (p) {
        var c = p.split(","); return '<circle cx="' + c[0] + '" cy="' + c[1] + '" r="2.5" class="trend-pt"/>'; }).join(""), "sparkline") +
      '<span class="hint">before the first test → now (0 at the bottom, 1 at the top)</span>';
  }

  function radar(readings) {
    if (readings.length < 3) return '<p class="hint">The radar appears from the third reading; the table lists them.</p>';
    var n = readings.length, R = 80, c = 100, top = 0;
    readings.forEach(function (r) { top = Math.max(top, r.force_N || 0, r.predicted_N || 0); });
    function poly(key) {
      return readings.map(function (r, i) {
        var a = -Math.PI / 2 + 2 * Math.PI * i / n, v = (r[key] || 0) / top * R;
        return (c + v * Math.cos(a)).toFixed(1) + "," + (c + v * Math.sin(a)).toFixed(1);
      }).join(" ");
    }
    var axes = readings.map(function (r, i) {
      var a = -Math.PI / 2 + 2 * Math.PI * i / n, x = c + (R + 6) * Math.cos(a), y = c + (R + 6) * Math.sin(a);
      return '<line x1="' + c + '" y1="' + c + '" x2="' + (c + R * Math.cos(a)).toFixed(1) + '" y2="' + (c + R * Math.sin(a)).toFixed(1) + '" class="axis"/>' +
        '<text x="' + x.toFixed(1) + '" y="' + y.toFixed(1) + '" class="' + (r.retest ? "flagtext" : "") + '" text-anchor="' + (Math.cos(a) > 0.3 ? "start" : Math.cos(a) < -0.3 ? "end" : "middle") + '">' + esc(r.test) + '</text>';
    }).join("");
    return svg(200, 200, axes + '<polygon points="' + poly("predicted_N") + '" class="pred"/><polygon points="' + poly("force_N") + '" class="meas"/>', "radar-svg") +
      '<p class="hint"><span class="k meas"></span> measured <span class="k pred"></span> model\'s prediction (outer ring ' + fmt(top) + ' N)</p>';
  }

  /* ---- test page ---- */
  function testPage(name) {
    var base = "/api/sessions/" + encodeURIComponent(name), cur = null, trials = [], restTimer = null;

    function render(st) {
      cur = st;
      var snap = st.snapshot, v = st.view, p = snap.proposal;
      $("step").textContent = "Step " + snap.step + " · " + snap.n_tested + " of " + snap.n_tests + " tests done";
      $("participant").textContent = "· " + snap.participant + " · " + snap.model;
      if (p && p.test) {
        $("proposed").textContent = (p.posture && p.posture !== "neutral" ? "Posture " + p.posture + " · " : "") + "Test: " + p.direction;
        $("where").textContent = (snap.postures ? "Hold the head in posture " + p.posture + ". " : "") + p.where;
        $("head").innerHTML = headViews(st.geometry, p.direction);
      } else {
        $("proposed").textContent = p ? "Every remaining test is skipped" : "Every test is done";
        $("where").textContent = "Stop to write the summary, or undo."; $("head").innerHTML = "";
      }
      $("record").disabled = !(p && p.test) && !$("other-test").value;
      $("recommendation").textContent = (st.stopped ? "This session was stopped and its summary written (end page); a new entry continues it. " : "") + snap.recommendation.text;
      $("recommendation").className = "recommendation" + (snap.recommendation.stop ? " stop" : "");
      $("alternatives").innerHTML = p ? bars(p.alternatives) : "";
      $("alt-label").textContent = p ? p.score_name + " (" + p.units + ") of each remaining test, best first" : "";
      var d = v.deficit;
      $("deficit").innerHTML = d ? ('<p class="big" id="p-deficit">P(deficit) ' + fmt(d.p_deficit, 2) + (d.decision ? ' · <b>' + esc(d.decision) + '</b>' : "") + '</p>' +
        trend(d.trend) + '<p class="label' + (d.calibrated ? " calibrated" : " heuristic") + '" id="deficit-label">' + esc(d.label) + '</p>' +
        (d.settings_label ? '<p class="hint">Depends on: ' + esc(d.settings_label) + '</p>' : "")) :
        '<p class="hint">This model has no deficit question (the deep-extensor group is not one of its groups).</p>';
      var pctCell = function (g) {
        var pct = g.pct_expected, w = Math.min(Math.max(pct || 0, 0), 200) / 2, sd = Math.min((g.pct_sd || 0) / 2, 50);
        return '<span class="pctbar"><span class="fill" style="width:' + w.toFixed(1) + '%"></span><span class="sd" style="left:' + Math.max(w - sd, 0).toFixed(1) + '%;width:' + (2 * sd).toFixed(1) + '%"></span><span class="ref"></span></span> ' + fmt(pct) + ' % ± ' + fmt(g.pct_sd);
      };
      var paired = v.asymmetry.length > 0, byCode = {};
      v.groups.forEach(function (g) { (byCode[g.code] = byCode[g.code] || []).push(g); });
      $("groups").tHead.innerHTML = paired ? '<tr><th>group</th><th>right: % of expected</th><th>left</th><th>right − left</th></tr>' :
        '<tr><th>group</th><th>% of expected</th><th>estimate</th></tr>';
      $("groups").tBodies[0].innerHTML = Object.keys(byCode).map(function (code) {
        var gs = byCode[code], g = gs[0];
        if (paired && gs.length === 2) {
          var a = v.asymmetry.filter(function (x) { return x.code === code; })[0];
          return '<tr><td>' + esc(g.name) + ' <span class="code">' + esc(code) + '</span></td><td title="' + fmt(gs[0].estimate_N) + ' ± ' + fmt(gs[0].sd_N) + ' N">' + pctCell(gs[0]) + '</td><td title="' + fmt(gs[1].estimate_N) + ' ± ' + fmt(gs[1].sd_N) + ' N">' + pctCell(gs[1]) + '</td><td>' + (a ? fmt(a.right_minus_left_pct) + ' %' : "") + '</td></tr>';
        }
        return gs.map(function (g) {
          return '<tr><td title="' + esc(g.muscle) + '">' + esc(g.name) + (g.side ? " (" + g.side + ")" : "") + ' <span class="code">' + esc(g.muscle) + '</span></td><td>' + pctCell(g) + '</td><td>' + fmt(g.estimate_N) + ' ± ' + fmt(g.sd_N) + ' N</td>' + (paired ? '<td></td>' : '') + '</tr>';
        }).join("");
      }).join("");
      $("reference-label").textContent = v.reference_label;
      $("uncertainty-label").textContent = "± : " + v.uncertainty_label;
      $("asymmetry").innerHTML = paired ? '<p class="hint">right − left: the difference of the two sides\' estimates over their mean (hover a cell for the estimate in N).</p>' : "";
      $("radar").innerHTML = radar(v.readings);
      $("readings").tBodies[0].innerHTML = v.readings.map(function (r) {
        return '<tr' + (r.retest ? ' class="retest"' : "") + '><td>' + esc(r.test) + '</td><td>' + fmt(r.force_N) + ' N</td><td>' + fmt(r.predicted_N) + ' N</td><td>' +
          (r.retest ? '<span class="flag">re-test? ' + (r.diff_pct > 0 ? "+" : "") + fmt(r.diff_pct) + ' %</span>' : "") + '</td></tr>'; }).join("");
      $("retest-label").textContent = v.retest_label + ". " + snap.predicted_label;
      $("legend").innerHTML = v.legend.map(function (l) { return '<dt>' + esc(l.code) + '</dt><dd>' + esc(l.name) + (l.where ? ": " + esc(l.where) : "") + '</dd>'; }).join("");
      $("screen").textContent = snap.screen;
      emgFields(snap.emg);
      var sel = $("other-test"), keep = sel.value;
      sel.innerHTML = '<option value="">the proposed test</option>' + snap.remaining.map(function (t) { return '<option>' + esc(t) + '</option>'; }).join("");
      sel.value = snap.remaining.indexOf(keep) >= 0 ? keep : "";
    }

    function fail(e, where) {
      if (e.status === 409) { $("load-error").textContent = e.message.replace(/^name: /, ""); }
      $(where || "force-error").textContent = e.message;
    }
    function after(ans) { $("message").textContent = ans.message + (ans.note ? " · " + ans.note : ""); $("force-error").textContent = ""; render(ans.state); }
    function load() { return api("GET", base).then(render).catch(function (e) { fail(e, "load-error"); }); }

    function parseForce(txt) {
      txt = txt.trim().replace(/\s*N$/i, "");
      if (txt === "") throw new Error("force: enter the measured force in N, e.g. 142");
      var f = Number(txt);
      if (!isFinite(f)) throw new Error("force: '" + txt + "' is not a number (in N, e.g. 142)");
      return f;   // the server checks the range and names the problem
    }
    var emgShown = null;
    function emgFields(e) {   // one numeric field per EMG channel of the session (chosen on the start page)
      var chans = e.channels === null ? e.choices.surface.concat(e.choices.deep) : e.channels, key = JSON.stringify(chans);
      if (key === emgShown) return;
      emgShown = key;
      $("emg-summary").textContent = chans.length ? "(" + chans.length + " channel" + (chans.length > 1 ? "s" : "") + ", optional)" : "(none recorded)";
      $("emg-fields").innerHTML = chans.map(function (m) {
        return '<label>' + esc(m) + '<input type="number" class="emg-in" data-channel="' + esc(m) + '" id="emg-' + esc(m) + '" min="0" max="1" step="any" inputmode="decimal" placeholder="0-1"></label>'; }).join("");
      $("emg-label").textContent = chans.length ? e.label + (e.channels === null ? "; channels not chosen at the start: the model's EMG channels" : "") + ". An empty field: not recorded in this test." :
        "No EMG channel was chosen when this session started: forces only.";
    }
    function emg() {          // {channel: value} of the filled fields; an error naming the channel for a bad value
      var out = {}, n = 0;
      document.querySelectorAll("#emg-fields input.emg-in").forEach(function (el) {
        var t = el.value.trim(), ch = el.getAttribute("data-channel"); el.setAttribute("aria-invalid", "false");
        if (el.validity && el.validity.badInput) { el.setAttribute("aria-invalid", "true"); throw new Error("EMG " + ch + ": not a number (a fraction of maximum, 0-1)"); }
        if (t === "") return;
        var a = Number(t);
        if (!isFinite(a)) { el.setAttribute("aria-invalid", "true"); throw new Error("EMG " + ch + ": '" + t + "' is not a number (a fraction of maximum, 0-1)"); }
        if (a < 0 || a > 1) { el.setAttribute("aria-invalid", "true"); throw new Error("EMG " + ch + ": " + t + " is outside 0-1 (a fraction of maximum, not %)"); }
        out[ch] = a; n += 1;
      });
      return n ? out : undefined;
    }
    function clearEmg() { document.querySelectorAll("#emg-fields input.emg-in").forEach(function (el) { el.value = ""; }); }
    var busy = false;
    function guard(fn) {      // one request at a time from this page (a double click does not send twice)
      return function () {
        if (busy) return Promise.resolve();
        busy = true; document.body.classList.add("busy");
        var btns = document.querySelectorAll("#test-card button"); btns.forEach(function (b) { b.disabled = true; });
        return fn.apply(null, arguments).then(function (x) { return x; }, function (e) { throw e; }).finally(function () {
          busy = false; document.body.classList.remove("busy"); btns.forEach(function (b) { b.disabled = false; });
        });
      };
    }
    function send(body) {
      var other = $("other-test").value;
      if (other) body.test = other;
      body.expect_step = cur.snapshot.step;
      var a = emg(); if (a) body.activations = a;
      return api("POST", base + "/tell", body).then(function (ans) { trials = []; $("trials").hidden = true; $("force").value = ""; clearEmg(); $("other-test").value = ""; after(ans); $("force").focus(); });
    }
    function showTrials(msg) {
      var t = cur.trials, html = trials.map(function (f, i) { return "trial " + (i + 1) + ": " + fmt(f) + " N"; }).join(" · ");
      $("trials").hidden = false;
      $("trials").innerHTML = html + (msg ? '<br><span class="rest" id="rest">' + msg + '</span>' : "") + '<br><span class="hint">' + esc(t.rule) + '</span>';
    }
    function rest(n) {
      var left = cur.trials.rest_s; clearInterval(restTimer);
      showTrials("Rest " + left + " s, then trial " + n);
      restTimer = setInterval(function () { left -= 1; if (left <= 0) { clearInterval(restTimer); showTrials("Trial " + n + ": go"); return; }
        var r = $("rest"); if (r) r.textContent = "Rest " + left + " s, then trial " + n; }, 1000);
    }

    $("force-form").addEventListener("submit", function (ev) {
      ev.preventDefault();
      $("force-error").textContent = "";
      var f;
      try { f = parseForce($("force").value); emg(); } catch (e) { $("force-error").textContent = e.message; return; }
      if (!$("best-of").checked) { guard(send)({force_N: f}).catch(function (e) { fail(e); }); return; }
      trials.push(f); $("force").value = "";
      var t = cur.trials, need = trials.length < 2 || (trials.length === 2 && trials[1] > t.third_ratio * trials[0]);
      if (need && trials.length < t.max) { rest(trials.length + 1); return; }
      clearInterval(restTimer);
      guard(send)({trials_N: trials.slice()}).catch(function (e) { trials = []; $("trials").hidden = true; fail(e); });
    });
    function post(what) { return function () { return api("POST", base + "/" + what, {expect_step: cur.snapshot.step}).then(after); }; }
    $("skip").addEventListener("click", function () { guard(post("skip"))().catch(function (e) { fail(e); }); });
    $("undo").addEventListener("click", function () { guard(post("undo"))().catch(function (e) { fail(e); }); });
    $("stop").addEventListener("click", function () {
      $("stop").disabled = true; $("message").textContent = "Writing the summary …";
      api("POST", base + "/stop", {expect_step: cur.snapshot.step}).then(function () { location.href = "/s/" + encodeURIComponent(name) + "/end"; })
        .catch(function (e) { $("stop").disabled = false; fail(e); });
    });
    $("other-test").addEventListener("change", function () { $("record").disabled = false; });
    load().then(function () { $("force").focus(); });
  }

  /* ---- end page ---- */
  function endPage(name) {
    var base = "/api/sessions/" + encodeURIComponent(name);
    $("save-report").addEventListener("click", function () {
      api("POST", base + "/report").then(function (a) { $("report-msg").textContent = "written: " + a.report_html; })
        .catch(function (e) { $("report-msg").textContent = e.message; });
    });
    $("close").addEventListener("click", function () {
      api("POST", base + "/close").then(function () { location.href = "/"; }).catch(function (e) { $("report-msg").textContent = e.message; });
    });
  }

  return {api: api, startPage: startPage, testPage: testPage, endPage: endPage};
})();
