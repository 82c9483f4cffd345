"""The clinician's session in a browser, and an ask/tell HTTP API (``neckstrength app``; docs/app.md)
==================================================================================================

The web layer only: every number comes from :class:`neckstrength.session.Session`, the engine the terminal uses,
with the same fsync'd log, so a session moves between the terminal and the browser with identical numbers.

- :mod:`.server`    :func:`create_app`: the JSON API (OpenAPI schema at ``/openapi.json``) and the pages
- :mod:`.sessions`  :class:`Registry`: one engine per session folder, each behind a lock
- :mod:`.security`  the access token, the Host check, no cross-site writes
- :mod:`.words`     the numbers in a clinician's words (group names, % of expected, asymmetry, re-test flags)
- :mod:`.serve`     :func:`serve`: bind 127.0.0.1 on a free port, print the URL with its token, open the browser
"""

from neckstrength.app.serve import new_token, serve
from neckstrength.app.server import create_app
from neckstrength.app.sessions import Registry
from neckstrength.app.words import clinician_view

__all__ = ["create_app", "serve", "new_token", "Registry", "clinician_view"]
