"""The web application: the ask/tell JSON API and the pages, on top of the session engine
=======================================================================================

:func:`create_app` returns a FastAPI (Starlette) application serving

- the **API** under ``/api`` (JSON; its OpenAPI schema at ``/openapi.json``): list and create sessions, read the state,
  ask for the next test, tell a measurement (posture, direction, force or best-of-N trials, optional EMG, trial
  number), skip, undo, stop, export, close; bad input gets a 4xx whose ``detail[].loc`` names the field;
- the **pages** (server-rendered with Jinja2, a little vanilla JavaScript calling the same API): start, test, end and
  the one-page report.

Every number comes from :class:`neckstrength.session.Session` (the same engine and log as the terminal);
:mod:`.words` only rewords them. One :class:`~.sessions.Registry` keeps one engine per session folder behind a lock.
"""

from __future__ import annotations

import base64
import json
import math
import time
from pathlib import Path
from typing import Literal

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from pydantic import BaseModel, ConfigDict, Field
from starlette.exceptions import HTTPException as StarletteHTTPException

from neckstrength.app.security import LOCAL_HOSTS, TokenHostMiddleware
from neckstrength.app.sessions import NAME_RE, TRIALS, Conflict, NotFound, Registry, check_name
from neckstrength.app.words import clinician_view
from neckstrength.errors import InputError, SessionLockedError
from neckstrength.session import (
    CRITERIA,
    LOG,
    MODELS,
    Entry,
    SessionOptions,
    emg_choices,
    parse_activations,
    parse_force,
)

HERE = Path(__file__).parent
EXPORTS = ("summary.csv", "summary.png", "steps.csv", "measurements.csv", "report.html", "session.json",
           "session.log.jsonl", TRIALS)
REPORT = "report.html"
MAX_TRIALS = 5
THIRD_TRIAL_RATIO = 1.10     # Appendix A: a third trial when the second exceeds the first by more than 10 %
DEFAULT_REST_S = 60          # rest between trials: the clinic's choice (Appendix A states none); the page's default


class FieldError(Exception):
    """Bad input naming its field (-> 422)."""

    def __init__(self, field: str | tuple, msg: str, where: str = "body"):
        super().__init__(msg)
        self.loc = [where, *field] if isinstance(field, tuple) else [where, field]
        self.msg = msg


def _detail(status: int, loc, msg: str, kind: str) -> JSONResponse:
    return JSONResponse({"detail": [{"loc": list(loc), "msg": msg, "type": kind}]}, status_code=status)


# -- request bodies (unknown fields are errors) -------------------------------------------------------------------
class CreateBody(BaseModel):
    """A new session: the options of ``neckstrength session start`` (None: the config's default)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern="^" + NAME_RE.pattern + "$", description="session folder name under the app's root")
    participant: str = Field("anonymous", min_length=1, max_length=100)
    model: Literal[MODELS] = "p2m7"
    criterion: Literal[CRITERIA] | None = None
    n_candidates: int | None = Field(None, ge=100, description="candidates (default: config)")
    postures: str | None = Field(None, max_length=500, description="comma-separated posture names or 'all'; None: "
                                                                   "neutral only")
    posture_change_cost: float = Field(0.0, ge=0, le=100, description="nats charged per posture change")
    prevalence: float | None = Field(None, gt=0, lt=1, description="prior P(deficit) of the decision")
    noise: float | None = Field(None, gt=0, le=1, description="sd of the relative force error (decision)")
    noise_source: str | None = Field(None, max_length=200)
    seed: int | None = Field(None, ge=0, le=2**32 - 1)
    prior_scale: float = Field(1.0, gt=0, le=10)
    stop_frac: float | None = Field(None, gt=0, lt=1)
    priorities: dict[str, float] = Field(default_factory=dict, description="Eq. 6.8 weights {muscle: weight >= 0}")
    emg_channels: list[str] | None = Field(None, max_length=64,
                                           description="the EMG channels recorded (muscles of GET /api/sessions "
                                                       "'emg'; or 'surface', 'deep', 'all'); None: not chosen, any "
                                                       "muscle's activation accepted; []: no EMG")


class TellBody(BaseModel):
    """One measurement. The test: ``test`` (``posture:direction`` or a direction), or ``direction`` (and
    ``posture``), or none of them for the proposed test. The force: ``force_N`` or ``trials_N`` (best of N, as
    Appendix A takes the largest of 2-3 trials)."""

    model_config = ConfigDict(extra="forbid")
    test: str | None = Field(None, max_length=200)
    direction: str | None = Field(None, max_length=200)
    posture: str | None = Field(None, max_length=100)
    force_N: float | None = Field(None, description="the measured force in N (0 < F <= 2000)")
    trials_N: list[float] | None = Field(None, min_length=1, max_length=MAX_TRIALS,
                                         description="the forces of repeat trials in N; the largest is recorded")
    trial: int | None = Field(None, ge=1, le=MAX_TRIALS, description="which trial force_N came from (recorded)")
    activations: dict[str, float] | None = Field(None, description="EMG activations {channel: fraction of maximum "
                                                                   "in [0, 1]}, the session's EMG channels only")
    expect_step: int | None = Field(None, ge=1, description="the step the client showed; 409 when the session has "
                                                            "moved on (another tab or client)")


class StepBody(BaseModel):
    """Skip, undo or stop; ``expect_step`` as for tell; ``test`` (skip only): default the proposed test."""

    model_config = ConfigDict(extra="forbid")
    test: str | None = Field(None, max_length=200)
    expect_step: int | None = Field(None, ge=1)


def _label(s, body: TellBody) -> str | None:
    if body.test is not None and (body.direction is not None or body.posture is not None):
        raise FieldError("test", "give either test or direction (and posture), not both")
    if body.test is not None:
        return body.test
    if body.direction is None:
        if body.posture is not None:
            raise FieldError("direction", "posture given without direction")
        return None
    if body.posture is not None and body.posture != "neutral":
        return f"{body.posture}:{body.direction}"
    return body.direction


def _last_action(folder: Path) -> str | None:
    try:
        lines = (folder / LOG).read_bytes().splitlines()
        return json.loads(lines[-1])["action"] if lines else None
    except (OSError, ValueError, KeyError, IndexError):
        return None


def create_app(root: str | Path = "sessions", token: str = "", config: str = "config/config.yaml",
               cache: str | None = None, threads: int | None = None, max_candidates: int = 2_000_000,
               hosts=LOCAL_HOSTS) -> FastAPI:
    """The application for the sessions under ``root`` (``token``: the access token; empty = refuse everything).
    ``max_candidates`` bounds a new session's candidate count (the API refuses more)."""
    if not token:
        raise ValueError("create_app needs an access token")
    reg = Registry(root, config, cache, threads)
    app = FastAPI(title="neckstrength session API", version="1",
                  description="The clinician's session (ask/tell) on top of neckstrength.session.Session; every "
                              "request needs the access token (URL ?token=, header X-Neckstrength-Token, or the "
                              "cookie for GET). docs/app.md.",
                  docs_url=None, redoc_url=None)     # the interactive docs load scripts from a CDN: not offline
    app.state.registry = reg
    app.add_middleware(TokenHostMiddleware, token=token, hosts=hosts)
    app.mount("/static", StaticFiles(directory=HERE / "static"), name="static")
    pages = Jinja2Templates(directory=HERE / "templates")

    # -- errors: 4xx naming the field, never a 500 for bad input
    @app.exception_handler(RequestValidationError)
    async def _invalid(request, exc):
        out = []
        for e in exc.errors():
            out.append({"loc": [str(x) for x in e.get("loc", ())], "msg": str(e.get("msg", "")),
                        "type": str(e.get("type", ""))})
        return JSONResponse({"detail": out}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request, exc):
        what = {404: "no such page or API path", 405: f"method {request.method} is not allowed here"}
        return JSONResponse({"detail": [{"loc": ["path"], "msg": what.get(exc.status_code, str(exc.detail)),
                                         "type": "http"}]}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(FieldError)
    async def _field(request, exc):
        return _detail(422, exc.loc, exc.msg, "value_error")

    @app.exception_handler(NotFound)
    async def _nf(request, exc):
        return _detail(404, ["path", "name"], str(exc), "not_found")

    @app.exception_handler(Conflict)
    async def _conflict(request, exc):
        return _detail(409, ["path", "name"], str(exc), "conflict")

    # -- the state a screen shows
    def state(o) -> dict:
        s = o.session
        snap = s.snapshot()
        geo = {r["name"]: {"point": [r["px"], r["py"], r["pz"]], "normal": [r["nx"], r["ny"], r["nz"]]}
               for r in s.dirtable.to_dict("records")}
        return {"session": o.name, "stopped": _last_action(s.out) == "stop", "snapshot": snap,
                "view": clinician_view(snap), "geometry": geo, "muscles": s.muscles,
                "outputs": [f for f in EXPORTS if (s.out / f).is_file()],
                "trials": {"max": MAX_TRIALS, "third_ratio": THIRD_TRIAL_RATIO, "rest_s": DEFAULT_REST_S,
                           "rule": "Appendix A: at least 2 trials, a third when the second exceeds the first by more "
                                   "than 10%; the largest is recorded. Rest between trials: the clinic's choice "
                                   f"(default {DEFAULT_REST_S} s; Appendix A states none)"}}

    def _check_step(s, expect: int | None):
        if expect is not None and expect != len(s.state.tested) + 1:
            raise Conflict(f"the session has moved on (now at step {len(s.state.tested) + 1}, you sent step {expect}: "
                           "another tab or client changed it); reload to see its state")

    def _name(name: str) -> str:
        try:
            return check_name(name)
        except ValueError as exc:
            raise FieldError("name", str(exc), "path") from None

    # -- the API
    emg_by_model: dict = {}

    def emg_offer() -> dict:
        """{model: {"surface": [...], "deep": [...]}}: the EMG channels a new session of each model offers (the
        engine's :func:`~neckstrength.session.emg_choices` on the app's config; computed once)."""
        if not emg_by_model:
            from neckstrength.config import full_model_from_config, load_config, model_from_config, session_settings

            cfg = load_config(reg.config)
            full = full_model_from_config(cfg)
            for m in MODELS:
                muscles = list(model_from_config(full, cfg, m).muscle_names)
                cs = session_settings(cfg, m)
                emg_by_model[m] = emg_choices(muscles, cs.emg_groups, cs.decision.group_indices(muscles))
        return emg_by_model

    @app.get("/api/sessions", tags=["sessions"], summary="the sessions in the app's folder")
    def list_sessions():
        return {"root": str(reg.root), "sessions": reg.listing(), "models": list(MODELS), "criteria": list(CRITERIA),
                "emg": emg_offer()}

    @app.post("/api/sessions", status_code=201, tags=["sessions"], summary="create a session")
    def create_session(body: CreateBody):
        if body.n_candidates is not None and body.n_candidates > max_candidates:
            raise FieldError("n_candidates", f"n_candidates {body.n_candidates} is above this app's bound "
                                             f"{max_candidates}")
        opts = SessionOptions(model=body.model, participant=body.participant, priorities=dict(body.priorities),
                              config=reg.config, n_candidates=body.n_candidates, prior_scale=body.prior_scale,
                              gain_frac=body.stop_frac, cache=reg.cache, seed=body.seed, criterion=body.criterion,
                              postures=body.postures, posture_change_cost=body.posture_change_cost,
                              prevalence=body.prevalence, noise=body.noise, noise_source=body.noise_source,
                              emg_channels=body.emg_channels)
        try:
            o = reg.create(body.name, opts)
        except ValueError as exc:
            raise FieldError(_option_field(str(exc)), str(exc)) from None
        with o.lock:
            return state(o)

    @app.get("/api/sessions/{name}", tags=["sessions"], summary="the state: everything a screen shows")
    def read_state(name: str):
        with reg.using(_name(name)) as o:
            return state(o)

    @app.get("/api/sessions/{name}/ask", tags=["ask/tell"], summary="the next test and its alternatives")
    def ask(name: str):
        with reg.using(_name(name)) as o:
            s = o.session
            return {"step": len(s.state.tested) + 1, "proposal": s.propose(),
                    "recommendation": dict(zip(("stop", "text"), s.recommendation(s.proposal())))}

    @app.post("/api/sessions/{name}/tell", tags=["ask/tell"], summary="a measurement")
    def tell(name: str, body: TellBody):
        with reg.using(_name(name)) as o:
            s = o.session
            _check_step(s, body.expect_step)
            if (body.force_N is None) == (body.trials_N is None):
                raise FieldError("force_N", "give the force: force_N (N) or trials_N (the forces of repeat trials)")
            if body.trials_N is not None and body.trial is not None:
                raise FieldError("trial", "trial goes with force_N (trials_N numbers the trials itself)")
            label = _label(s, body)
            try:
                test = s.parse(f"measure {label} 1").direction if label is not None else s.choice(s.proposal())
            except InputError as exc:
                raise FieldError("posture" if "posture" in str(exc) and body.posture else
                                 "test" if body.test is not None else "direction", str(exc)) from None
            if test is None:
                raise FieldError("direction", "no test is proposed: name the test (direction and posture)")
            forces = body.trials_N if body.trials_N is not None else [body.force_N]
            for i, f in enumerate(forces):
                try:
                    parse_force(repr(float(f)))
                except InputError as exc:
                    raise FieldError("trials_N" if body.trials_N is not None else "force_N",
                                     (f"trial {i + 1}: " if body.trials_N is not None else "") + str(exc)) from None
            force = parse_force(repr(float(max(forces))))
            acts = None
            if body.activations:
                acts = {}
                for k, v in body.activations.items():
                    loc = ("activations", k)
                    if not k or any(c in k for c in ",:=") or k not in s.muscles:
                        raise FieldError(loc, f"'{k}' is not a muscle of this model; EMG channels of this session: "
                                              f"{', '.join(s.emg_channels if s.emg_channels is not None else s.muscles)}")
                    try:
                        s.check_activations({k: 0.0})
                        acts.update(parse_activations(f"act={k}:{float(v)!r}", s.muscles))
                    except InputError as exc:
                        raise FieldError(loc, str(exc)) from None
            try:
                ans = s.tell(Entry("measure", test, force, acts))
            except InputError as exc:
                raise FieldError("direction", str(exc)) from None
            if body.trials_N is not None or body.trial is not None:
                _write_trials(s.out, ans["record"], forces, body.trial)
            out = {"record": ans["record"], "message": ans["message"], "state": state(o)}
            if body.trials_N is not None and len(forces) == 2 and forces[1] > THIRD_TRIAL_RATIO * forces[0]:
                out["note"] = ("Appendix A would take a third trial: the second exceeded the first by more than 10%")
            return out

    @app.post("/api/sessions/{name}/skip", tags=["ask/tell"], summary="skip a test (default: the proposed one)")
    def skip(name: str, body: StepBody | None = None):
        body = body or StepBody()
        with reg.using(_name(name)) as o:
            s = o.session
            _check_step(s, body.expect_step)
            test = body.test if body.test is not None else s.choice(s.proposal())
            if test is None:
                raise FieldError("test", "nothing to skip: no test is proposed")
            try:
                ans = s.tell(Entry("skip", test))
            except InputError as exc:
                raise FieldError("test", str(exc)) from None
            return {"record": ans["record"], "message": ans["message"], "state": state(o)}

    @app.post("/api/sessions/{name}/undo", tags=["ask/tell"], summary="undo the last measurement or skip")
    def undo(name: str, body: StepBody | None = None):
        body = body or StepBody()
        if body.test is not None:
            raise FieldError("test", "undo takes no test: it removes the last measurement or skip")
        with reg.using(_name(name)) as o:
            _check_step(o.session, body.expect_step)
            try:
                ans = o.session.undo()
            except InputError as exc:
                raise FieldError("action", str(exc)) from None
            return {"record": ans["record"], "message": ans["message"], "state": state(o)}

    @app.post("/api/sessions/{name}/stop", tags=["ask/tell"],
              summary="stop: writes summary.csv, summary.png, steps.csv, measurements.csv and report.html")
    def stop(name: str, body: StepBody | None = None):
        body = body or StepBody()
        if body.test is not None:
            raise FieldError("test", "stop takes no test")
        with reg.using(_name(name)) as o:
            _check_step(o.session, body.expect_step)
            ans = o.session.stop()
            st = state(o)
            rep = _write_report(o.session.out, render_report(st))
            outputs = {k: Path(v).name for k, v in ans["outputs"].items()} | {"report_html": rep.name}
            st["outputs"] = [f for f in EXPORTS if (o.session.out / f).is_file()]
            return {"record": ans["record"], "message": ans["message"], "outputs": outputs, "state": st}

    @app.post("/api/sessions/{name}/report", tags=["export"], summary="write the one-page report.html to the folder")
    def export_report(name: str):
        with reg.using(_name(name)) as o:
            rep = _write_report(o.session.out, render_report(state(o)))
            return {"report_html": rep.name, "path": str(rep)}

    @app.get("/api/sessions/{name}/files/{file}", tags=["export"], summary="a file of the session folder")
    def get_file(name: str, file: Literal[EXPORTS]):
        folder = reg.folder(_name(name))
        if not (folder / file).is_file():
            raise FieldError("file", f"{file} does not exist (yet) in session '{name}': stop the session to write "
                                     "the summary files", "path")
        kind = {"csv": "text/csv", "png": "image/png", "html": "text/html", "json": "application/json",
                "jsonl": "application/json"}[file.rsplit(".", 1)[1]]
        return FileResponse(folder / file, media_type=kind,
                            filename=None if kind in ("image/png", "text/html") else f"{name}_{file}")

    @app.post("/api/sessions/{name}/close", tags=["sessions"],
              summary="give the folder back (e.g. to resume it in the terminal)")
    def close(name: str):
        return {"closed": reg.close(_name(name))}

    # -- the pages
    def page(request: Request, template: str, **ctx):
        return pages.TemplateResponse(request, template, {"token": token, **ctx})

    def render_report(st: dict) -> str:
        png = Path(reg.folder(st["session"])) / "summary.png"
        img = base64.b64encode(png.read_bytes()).decode() if png.is_file() else None
        return pages.get_template("one_page_report.html").render(st=st, img=img, now=time.strftime("%Y-%m-%d %H:%M"),
                                                        fmt=_fmt)

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def start_page(request: Request):
        return page(request, "start.html", sessions=reg.listing(), models=MODELS, criteria=CRITERIA,
                    root=str(reg.root), emg=emg_offer())

    @app.get("/s/{name}", response_class=HTMLResponse, include_in_schema=False)
    def test_page(request: Request, name: str):
        return page(request, "test.html", name=_name(name))

    @app.get("/s/{name}/end", response_class=HTMLResponse, include_in_schema=False)
    def end_page(request: Request, name: str):
        with reg.using(_name(name)) as o:
            st = state(o)
        return page(request, "end.html", st=st, name=name, fmt=_fmt)

    @app.get("/s/{name}/report", response_class=HTMLResponse, include_in_schema=False)
    def report_page(request: Request, name: str):
        with reg.using(_name(name)) as o:
            return HTMLResponse(render_report(state(o)))

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon():
        return RedirectResponse("/static/favicon.svg")

    app.router.on_shutdown.append(reg.close_all)
    return app


def _fmt(x, nd: int = 0, suffix: str = "") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{nd}f}{suffix}"


def _option_field(msg: str) -> str:
    for key, field in (("--emg", "emg_channels"), ("--posture-change-cost", "posture_change_cost"), ("--postures", "postures"),
                       ("criterion", "criterion"), ("priorit", "priorities"), ("prevalence", "prevalence"),
                       ("noise", "noise"), ("n_candidates", "n_candidates"), ("exists", "name")):
        if key in msg:
            return field
    return "body"


def _write_trials(folder: Path, record: dict, forces, trial) -> None:
    """Append the repeat trials of an acknowledged measurement to the app's ``trials.jsonl`` (fsync'd)."""
    import os

    line = json.dumps({"seq": record["seq"], "direction": record["direction"], "force_N": record["force_N"],
                       "trials_N": [float(f) for f in forces], "trial": trial}) + "\n"
    with open(folder / TRIALS, "a", encoding="utf-8") as fh:
        fh.write(line)
        fh.flush()
        os.fsync(fh.fileno())


def _write_report(folder: Path, html: str) -> Path:
    import os

    path = folder / REPORT
    tmp = folder / (REPORT + ".tmp")
    tmp.write_text(html, encoding="utf-8")
    os.replace(tmp, path)
    return path
