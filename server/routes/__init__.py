"""The play server's HTTP and WebSocket routes, one ``APIRouter`` per concern; ``server.app.create_app`` includes
them. Each takes what it needs from this process's ``Backend`` (``server.backend.CurrentBackend``)."""
