"""Spatially sharded switchboards over NATS (issue 13).

`nats_proto` (sans-IO NATS text protocol) and `nats_client` (its trio shell); `core` (sans-IO cluster
logic: region ownership, mirrored remote entities, snapshots, REDIRECT decisions, failover rule) and `link`
(the trio shell joining a switchboard `Server` to NATS). The region partition is `topology.regions`.
"""
