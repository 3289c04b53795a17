"""The web dashboard: aiohttp server, WebSocket hub, REST API, static page."""
