"""Where a live monitor's committed conclusions go: the sinks of `outbox`'s contract (an MQTT
broker, a webhook, an OPC UA server), each handed what every commit holds."""
