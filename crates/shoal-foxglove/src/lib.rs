//! Shoal's Foxglove live bridge: the station's topics over the Foxglove WebSocket protocol.
