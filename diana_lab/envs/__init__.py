"""The navigation environment and its parts (action spaces, rewards, episodes, rendering)."""

ENV_ID = "diana_lab/RoverNav-v0"
