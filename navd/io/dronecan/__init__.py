"""DroneCAN (UAVCAN v0) adapter over python-can: CAN frames <-> navd.types.

One module per job:

transfer  frames <-> transfers: session reassembly (toggle, transfer ID, timeout) and
          serialisation into classic-CAN frames; knows no data types
decode    DronecanConfig, the accepted data type IDs, DronecanDecoder (transfer CRC,
          RawIMU / Fix2 / SkyPolarization -> samples)
encode    DronecanEncoder (NavSolution -> uavcan.equipment.ahrs.Solution frames)
link      open_bus and DronecanLink (python-can Notifier on the event loop, send)

``from navd.io.dronecan import X`` keeps working for every name below.  navd's private
DSDL type stays in ``navd/io/dsdl/`` (package data).
"""

from navd.io.dronecan.decode import (
    FIX2_DTID,
    POL_DTID,
    POL_SIGNATURE,
    RAW_IMU_DTID,
    DronecanConfig,
    DronecanDecoder,
    RawImuFields,
)
from navd.io.dronecan.encode import SOLUTION_DTID, DronecanEncoder
from navd.io.dronecan.link import DronecanLink, open_bus
from navd.io.dronecan.transfer import transfer_messages

__all__ = [
    "FIX2_DTID",
    "POL_DTID",
    "POL_SIGNATURE",
    "RAW_IMU_DTID",
    "SOLUTION_DTID",
    "DronecanConfig",
    "DronecanDecoder",
    "DronecanEncoder",
    "DronecanLink",
    "RawImuFields",
    "open_bus",
    "transfer_messages",
]
