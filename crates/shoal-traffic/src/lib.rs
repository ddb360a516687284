//! Shoal's traffic picture: AIS and NMEA 0183 inputs, surface targets and collision warnings (CPA/TCPA).
