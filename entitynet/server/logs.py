"""Structured logs: one event name plus key=value fields (or one JSON object per line with --log-json)."""

from __future__ import annotations

import json
import logging
import time

log = logging.getLogger("entitynet.server")


class JsonFormatter(logging.Formatter):
    """One JSON object per line with the event's fields as keys (--log-json), for log collectors."""

    def format(self, record: logging.LogRecord) -> str:
        """The record as JSON: time, level, logger, event name and the fields passed to `event`."""
        body = {"ts": round(record.created, 3), "level": record.levelname, "logger": record.name,
                "event": record.getMessage()}
        body.update(getattr(record, "fields", {}))
        return json.dumps(body, default=str)


def event(name: str, level: int = logging.INFO, **fields) -> None:
    """Log event `name` with key=value fields; the fields also ride on the record so that JSON output keeps
    them as keys. Nothing is formatted when the level is off."""
    if log.isEnabledFor(level):
        text = name + "".join(f" {k}={v}" for k, v in fields.items())
        log.log(level, text if not _json else name, extra={"fields": fields, "t": time.time()})


_json = False


def use_json(enabled: bool) -> None:
    """Switch the root handlers to JSON lines."""
    global _json
    _json = enabled
    if enabled:
        for h in logging.getLogger().handlers:
            h.setFormatter(JsonFormatter())
