"""navd: GNSS/INS attitude and heading daemon.

Conventions (stated once, used everywhere in the package)
---------------------------------------------------------
Frames
    n  local-level navigation frame, NED (north, east, down).
    b  body frame, FRD (forward, right, down), as MAVLink, PX4 and DroneCAN use.
    e  ECEF (WGS-84).
Attitude
    ``mat_nb`` is C_b^n (rotates body vectors into n).  Euler angles are ZYX:
    ``C = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, yaw clockwise from north seen from above.
    Quaternions are scalar-first ``(w, x, y, z)``, same rotation as ``mat_nb``.
Units
    SI inside (rad, m, m/s, s); degrees, mG, cm/s and 1e7-degree integers only at the
    wire.  Time stamps are integer microseconds ``t_us``; intervals ``dt_us`` / ``dt_s``.
    Geodetic position is ``(lat_rad, lon_rad, alt_m)`` on WGS-84, height above ellipsoid.
Errors
    Navigation errors are computed minus true.  Attitude error phi (NED, rad) is defined by
    ``C_hat = Exp(-phi) @ C``; velocity error ``dv = v_hat - v``; position error
    ``dp = (dlat, dlon, dh) = p_hat - p``.  The bias states are the residual error of the
    bias-compensated sensor (``b_true - b_hat``), so corrections are
    ``C <- Exp(phi) C_hat``, ``v <- v_hat - dv``, ``p <- p_hat - dp``, ``b <- b_hat + db``.
Error-state order (15)
    ``[phiN phiE phiD | dvN dvE dvD | dlat dlon dh | dbg_x dbg_y dbg_z | dba_x dba_y dba_z]``
    with the bias blocks in body FRD.
Names
    Vectors carry their frame: ``vel_n``, ``f_b``, ``omega_ie_n``; matrices ``mat_ab`` map
    frame b into frame a.
"""

__version__ = "0.1.0"
