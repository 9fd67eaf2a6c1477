"""Live views of a run while it happens: the Foxglove WebSocket server (`foxglove_server`) for the
node and for `prsm-bag serve` (`serve_bag`)."""
