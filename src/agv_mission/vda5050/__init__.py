"""VDA 5050 2.1 over MQTT: our simulated robots as vehicles, our missions as a master."""
