"""The records server: trainee records of a whole programme on one server (thesis 3.3.4, Fig. 3.11).

``chainsim serve`` runs ``app.build_app`` with uvicorn over the records store (SQLite file or
PostgreSQL): accounts and roles (``accounts``), request checks (``auth``), the JSON API
(``api``), the trainers' dashboard (``views``, ``plots``, ``templates/``, ``static/``). The
simulator's side, saving to a server with an offline queue, is ``client``; the load benchmark is
``bench``. docs/records-server.md describes it as a user sees it.
"""
