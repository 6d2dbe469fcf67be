"""The operator station: a page and a WebSocket for the person at the joystick (see README)."""
