"""Protocol v1: messages, codec and framing, sans-IO (DESIGN.md, "Protocol v1").

Frames over TCP are a 4-byte big-endian length followed by a msgpack payload (`framing`); over WebSocket one
binary message is one payload. A payload is a list of messages (`codec`); a message is a list starting with its
type (`messages`). The package re-exports every public name, so `from entitynet import protocol as P` and
`P.Update`, `P.encode_message`, `P.FrameDecoder`, ... work whichever module defines them.
"""

from entitynet.protocol.codec import (
    DEFAULT_LIMITS,
    CodecLimits,
    array_header,
    decode_payload,
    encode_leave,
    encode_message,
    encode_payload,
    encode_query_result,
    encode_update,
    payload_from_encoded,
)
from entitynet.protocol.framing import LENGTH_PREFIX, FrameDecoder, encode_frame, frame, frame_head, frame_prefix
from entitynet.protocol.messages import (
    CAMERA,
    ERROR,
    FATAL_ERRORS,
    FOLLOW,
    HELLO,
    LEAVE,
    LOCAL_ID_LIMIT,
    MAX_CELL,
    MAX_COORD,
    MAX_INT,
    MAX_VALIDITY_MS,
    PING,
    PONG,
    PRIVACY,
    PROTOCOL_VERSION,
    PUBLISH,
    QUERY,
    QUERY_CELLS,
    QUERY_IDENTITY,
    QUERY_RESULT,
    REDIRECT,
    SUBSCRIBE,
    UNFOLLOW,
    UNPUBLISH,
    UPDATE,
    WELCOME,
    Camera,
    Error,
    ErrorCode,
    Follow,
    Hello,
    Leave,
    Message,
    Ping,
    Pong,
    Privacy,
    ProtocolError,
    Publish,
    Query,
    QueryResult,
    Redirect,
    Subscribe,
    Unfollow,
    Unpublish,
    Update,
    Welcome,
    now_ms,
)

__all__ = [
    "CAMERA", "MAX_COORD", "Camera",
    "DEFAULT_LIMITS", "ERROR", "FATAL_ERRORS", "FOLLOW", "HELLO", "LEAVE", "LENGTH_PREFIX", "LOCAL_ID_LIMIT",
    "MAX_CELL", "MAX_INT", "MAX_VALIDITY_MS", "PING", "PONG", "PRIVACY", "PROTOCOL_VERSION", "PUBLISH", "QUERY",
    "QUERY_CELLS", "QUERY_IDENTITY", "QUERY_RESULT", "REDIRECT", "SUBSCRIBE", "UNFOLLOW", "UNPUBLISH", "UPDATE",
    "WELCOME", "CodecLimits", "Error", "ErrorCode", "Follow", "FrameDecoder", "Hello", "Leave", "Message", "Ping",
    "Pong", "Privacy", "ProtocolError", "Publish", "Query", "QueryResult", "Redirect", "Subscribe", "Unfollow",
    "Unpublish", "Update", "Welcome", "array_header", "decode_payload", "encode_frame", "encode_leave",
    "encode_message", "encode_payload", "encode_query_result", "encode_update", "frame", "frame_head",
    "frame_prefix", "now_ms", "payload_from_encoded",
]
