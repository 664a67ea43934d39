"""The live debug view: a web page per rig (images, the sent scan, status) and metrics.

Modules: :mod:`.render` (pictures, pure functions on arrays), :mod:`.views` (the daemon's
latest state as pictures, drawn only while watched), :mod:`.metrics` (Prometheus collector and
the ``/api/stats`` record from one snapshot), :mod:`.page` (the HTML) and :mod:`.server` (the
aiohttp server the daemon runs as one of its loops).
"""
