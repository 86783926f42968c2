"""The web gateway: a separate process beside the daemon (as Moonraker beside Klippy) that
serves a JSON HTTP API, a WebSocket and the console page, and talks to the daemon only
through its control socket (service.protocol), so no HTTP client can stall the cycle loop."""
