//! Foreign DDS implementations against the station (filled in below).
