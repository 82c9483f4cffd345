"""The example client of docs/app.md runs against the real app: it creates a session, tells three measurements as
best-of-2 trials, is refused a negative force with the field named, and stops."""

from __future__ import annotations

import re

from app_constants import ROOT, TOKEN


def test_docs_example_client(live_app, capsys):
    base, root = live_app
    text = (ROOT / "docs" / "app.md").read_text()
    code = re.search(r"A client in Python.*?```python\n(.*?)```", text, re.S).group(1)
    ns = {"__name__": "docs_client"}
    exec(compile(code, "docs/app.md", "exec"), ns)
    done = ns["run"](base, TOKEN)
    out = capsys.readouterr().out
    assert "refused: 422 force_N: force -5 N is negative" in out
    assert out.count("recorded ") == 3 and done["state"]["stopped"]
    assert (root / "P01-lab" / "summary.csv").is_file() and len(done["state"]["view"]["groups"]) == 7
