"""eca's small browser page for a pipecat bot on SmallWebRTC: the face (video) and voice (audio) in, the
microphone out, over one WebRTC connection to the bot's offer endpoint, `POST /api/offer` on the server that
serves the page (pipecat's development runner has it, and so has the example bot). Plain HTML and standard
WebRTC, no build step, nothing fetched from elsewhere. Serve it from your bot's FastAPI app:

    @app.get("/eca")
    async def page() -> HTMLResponse:
        return HTMLResponse(client_page())
"""

from __future__ import annotations

from importlib import resources


def client_page() -> str:
    """The page's HTML (shipped in the package, as `static/client.html`)."""
    return (resources.files(__package__) / "static" / "client.html").read_text(encoding="utf-8")
