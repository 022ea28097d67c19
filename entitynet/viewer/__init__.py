"""The browser viewer: a web page served by the switchboard that is itself an honest viewer client.

Python side: `geometry` (the artifact as the page draws it and extrapolates on it), `routes` (the HTTP routes of
`entitynet serve --http-port`). Browser side: `static/` (HTML and ES modules; `npm run build` bundles them with
deck.gl into `static/dist/viewer.js`). The page speaks protocol v1 over the server's WebSocket port.
"""
