"""Dashboard: FastAPI page with the live state over websockets."""
