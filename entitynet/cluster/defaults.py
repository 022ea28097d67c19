"""The cluster's default timings, in one place that imports nothing: the library (`nats_client`, `core`,
`link.ClusterConfig`) and the CLI's help texts (`entitynet serve --cluster`, read at every start) share them
without the CLI importing trio to print a default."""

#: seconds one NATS connect attempt may take (the first connection's deadline: this x max(2, servers) + 1 s)
CONNECT_TIMEOUT_S = 2.0
#: seconds of silence after which a shard is dead and its regions pass on
DEAD_AFTER_S = 2.0
