"""The network: ZeroMQ transport, direct (peer-to-peer) topics and their reach probes, the bus proxy and its latched-value cache, addresses, CURVE keys and handshakes, the wire envelope."""
