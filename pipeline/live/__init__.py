"""Live view: a run's results over the Foxglove WebSocket protocol as stages complete.

Modules:
    server: the foxglove-sdk WebSocket server, one channel per topic, replay on subscribe.
    feed: `on_stage` callback turning finished stages' artifacts into messages.
"""
