"""``hdrd web``: the live page of the published messages.

What the page shows of the messages (:mod:`~hdrd.io.web.webstate`), the HTTP and
server-sent-events server (:mod:`~hdrd.io.web.webserver`) and the page itself (``webpage/``:
HTML, JavaScript, CSS and an icon, shipped as package data).
"""
