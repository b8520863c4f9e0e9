"""GNSS models: from broadcast records and chosen observations to the linearized pseudoranges.

Modules, one job each::

    time         GPS time: seconds since the GPS epoch, leap seconds, week and seconds of week
    frames       ECEF, geodetic and local ENU frames; azimuth and elevation
    ephemeris    KeplerEphemeris: broadcast Keplerian records as flat arrays, their selection
    orbits       broadcast_states: Keplerian satellite positions, velocities and clocks (IS-GPS-200)
    multi_gnss   the Keplerian systems (Galileo, BeiDou with its GEO, QZSS, GPS): records, states
    glonass      GLONASS records: state vectors integrated with RK4, FDMA channels
    broadcast    GlonassRecords, KeplerRecords, system_records: one system's records behind one
                 interface; ephemeris_sigma_m, the orbit-and-clock sigma of a record (URA, SISA)
    observables  select_pseudoranges, select_dopplers, select_phases: one signal per satellite
    signals      carrier frequencies, group delays and the iono-free combination of a code
    atmosphere   Klobuchar ionosphere and Saastamoinen troposphere delays
    range_model  the pseudorange model (RTKLIB rescode): transmit time, satellite clock and group
                 delay, Sagnac, atmosphere, weights -> linearize: A, q, W
    doppler      range_rate_system: the Doppler system of receiver velocity and clock drift
    carrier      phase_slips: where a carrier phase may have slipped between epochs

Each module imports only the ones above it in this list (and ``io``, ``config``).
"""
