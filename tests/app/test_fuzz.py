"""Property-based test of the API against its own OpenAPI schema (hypothesis): requests built from the schema's
operations, path parameters and body properties, with values that follow the schema or break it (wrong types,
out of range, unknown fields, non-JSON bodies), never get a 500; every 4xx names where the problem is (``loc``).

New sessions are created only for p2m7 with the thesis's scheme (about a second each); other valid create
requests are pointed at the existing session (409), so the test stays within about half a minute. Derandomized:
the same 200 examples every run, so CI is repeatable."""

from __future__ import annotations

import json
from urllib.parse import quote

from app_constants import HDR, P2M7
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neckstrength.app.sessions import NAME_RE

SCALARS = st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=False) | st.text(max_size=12)
JSON = st.recursive(SCALARS, lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=6), c, max_size=3),
                    max_leaves=6)


VALID = {("post", "/api/sessions"): {"name": "F", "model": "p2m7"},
         ("post", "/api/sessions/{name}/tell"): {"force_N": 150.0}}


def _resolve(schema, spec):
    while isinstance(schema, dict) and "$ref" in schema:
        schema = spec["components"]["schemas"][schema["$ref"].rsplit("/", 1)[1]]
    return schema


def _value(draw, schema, spec, depth=0):
    """A value for ``schema``: mostly one of its own types (with its enums and bounds stretched), sometimes any JSON."""
    schema = _resolve(schema, spec)
    if depth > 2 or draw(st.integers(0, 9)) == 0:
        return draw(JSON)
    options = schema.get("anyOf") or schema.get("oneOf")
    if options:
        return _value(draw, draw(st.sampled_from(options)), spec, depth + 1)
    if "enum" in schema:
        return draw(st.sampled_from(schema["enum"]) | st.text(max_size=8))
    t = schema.get("type")
    if t == "string":
        return draw(st.sampled_from(["", "back", "neutral:back", "flex20:back", "TS-B", "all", "x" * 300])
                    | st.text(max_size=20))
    if t == "integer":
        return draw(st.integers(-5, 10) | st.integers(-2**40, 2**40))
    if t == "number":
        return draw(st.sampled_from([0, -1, 0.5, 1, 150, 2000, 2000.01, 1e308, -0.0]) | st.floats(-1e4, 1e4))
    if t == "boolean":
        return draw(st.booleans())
    if t == "null":
        return None
    if t == "array":
        return draw(st.lists(st.builds(lambda: None), max_size=6).map(len).flatmap(
            lambda n: st.just([_value(draw, schema.get("items", {}), spec, depth + 1) for _ in range(n)])))
    if t == "object":
        props = schema.get("properties", {})
        out = {}
        for k in draw(st.lists(st.sampled_from(sorted(props)), unique=True)) if props else []:
            out[k] = _value(draw, props[k], spec, depth + 1)
        if schema.get("additionalProperties") is not None and not props:
            for k in draw(st.lists(st.sampled_from(["TS-B", "TC-E", "SCM-R", "x", ""]), max_size=3, unique=True)):
                out[k] = _value(draw, schema["additionalProperties"] or {}, spec, depth + 1)
        if draw(st.integers(0, 9)) == 0:
            out[draw(st.text(min_size=1, max_size=6))] = draw(JSON)          # an unknown field
        return out
    return draw(JSON)


@st.composite
def requests_from(draw, spec, names):
    path = draw(st.sampled_from(sorted(spec["paths"])))
    ops = spec["paths"][path]
    method = draw(st.sampled_from(sorted(ops)))
    op = ops[method]
    url = path
    for p in op.get("parameters", []):
        if p["in"] == "path":
            v = (_value(draw, p.get("schema", {}), spec) if draw(st.integers(0, 3)) == 0 else
                 draw(st.sampled_from(names)) if p["name"] == "name" else
                 draw(st.sampled_from(p.get("schema", {}).get("enum", ["x"]))))
            url = url.replace("{" + p["name"] + "}", quote(str(v), safe="") or "x")
    body = None
    schema = op.get("requestBody", {}).get("content", {}).get("application/json", {}).get("schema")
    kind = draw(st.integers(0, 9))
    if kind == 0:
        body = ("raw", draw(st.binary(max_size=30)))
    elif schema is not None and 2 <= kind <= 5:        # a valid request with 0-2 fields set from the schema
        sch = _resolve(schema, spec)
        sch = _resolve(next((o for o in sch.get("anyOf", []) if o.get("type") != "null"), sch), spec)
        props = sch.get("properties") or {"": {}}
        b = dict(VALID.get((method, path), {}))
        if "name" in b:
            b["name"] = draw(st.sampled_from(["F", "G1", "G2"]))
        for k in draw(st.lists(st.sampled_from(sorted(props)), max_size=2, unique=True)):
            if k:
                b[k] = _value(draw, props[k], spec)
        body = ("json", b)
    elif schema is not None:
        body = ("json", _value(draw, schema, spec))
    elif kind == 1:
        body = ("json", draw(JSON))
    return method.upper(), url, body


def test_api_fuzz_finds_no_500(client):
    spec = client.get("/openapi.json").json()
    assert client.post("/api/sessions", json={"name": "F", **P2M7}).status_code == 201
    names = ["F", "F", "F", "G1", "nobody", "../F", "F.json"]
    created = []

    @settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(requests_from(spec, names))
    def one(req):
        method, url, body = req
        if method == "POST" and url == "/api/sessions" and body and body[0] == "json" and isinstance(body[1], dict):
            b = body[1]
            fresh = (isinstance(b.get("name"), str) and NAME_RE.fullmatch(b["name"])
                     and b.get("model", "p2m7") == "p2m7" and b.get("criterion") in (None, "thesis")
                     and len(created) < 3 and (b.get("n_candidates") is None or
                                              (isinstance(b["n_candidates"], int) and b["n_candidates"] <= 3000)))
            if fresh:
                b.setdefault("n_candidates", 500)
                created.append(b["name"])
            elif isinstance(b.get("name"), str) and NAME_RE.fullmatch(b["name"]) and b["name"] not in created:
                b["name"] = "F"                          # an existing session: 409 once the body is valid
        kw = {}
        if body is not None and body[0] == "raw":
            kw["content"] = body[1]
            kw["headers"] = {**HDR, "content-type": "application/json"}
        elif body is not None:
            kw["content"] = json.dumps(body[1]).encode()
            kw["headers"] = {**HDR, "content-type": "application/json"}
        r = client.request(method, url, **kw)
        assert r.status_code < 500, (method, url, body, r.status_code, r.text[:500])
        if 400 <= r.status_code < 500 and r.headers.get("content-type", "").startswith("application/json"):
            detail = r.json().get("detail")
            assert detail and all("loc" in d and "msg" in d for d in detail), r.text[:500]

    one()
