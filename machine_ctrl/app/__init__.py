"""The roof: bringup, process supervision, client, CLI, demo."""
