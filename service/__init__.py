"""The planning service: a FastAPI jobs API over ``planning.pipeline`` (``scanmill serve``).

``service/`` only translates HTTP into calls of the planning code and stores jobs and their files;
it holds no geometry. Layout: ``settings`` (SCANMILL_* configuration), ``store`` (SQLite job store),
``storage`` (files, atomic writes, safe names), ``workers`` (process-per-job runner), ``intake``
(upload validation), ``jobs`` (the use cases), ``auth``, ``problems`` (RFC 9457), ``limits``
(request sizes), ``routers/`` (thin HTTP routes) and ``app`` (the application factory).
"""
