"""Sinks: where batches go (Rerun viewer, MCAP archive, Zenoh). One module per destination."""
