"""Live 3D viewer of the stack (viser in the browser), fed by the Zenoh streams.

``python -m sqmanip.viewer [--host H] [--port P]`` (``sqmanip up`` starts it; default port
``StackSettings.viewer_port``). Modules: :mod:`.decode` (payloads -> updates, colours),
:mod:`.feeds` (Zenoh subscription), :mod:`.draw` (scene tree), :mod:`.controls` (side panel and
gateway actions), :mod:`.app` (the :class:`~sqmanip.viewer.app.Viewer` tying them together).
"""
