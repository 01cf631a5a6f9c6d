"""ArduPilot DataFlash (.bin) logs for tests: FMT records first, then the messages, as AP_Logger writes
them; the ArduPilot 4.x formats a calibration session needs (IMU, PARM, ARM, EV)."""
from __future__ import annotations

import os
import struct
from typing import Any

import numpy as np

# (message name, its field values in order): strings as str
Record = tuple[str, tuple[Any, ...]]

HEAD = b"\xa3\x95"
FMT_ID = 0x80

_STRUCT = {"Q": "Q", "q": "q", "B": "B", "b": "b", "H": "H", "h": "h", "I": "I", "i": "i", "f": "f", "d": "d",
           "n": "4s", "N": "16s", "Z": "64s", "M": "b",
           "c": "h", "C": "H", "e": "i", "E": "I"}  # c, C, e, E: 100 x the value as an integer (readers divide)


def write_dataflash(path: str | os.PathLike[str], formats: dict[str, tuple[str, str]], records: list[Record]) -> int:
    """A DataFlash log: `formats` {name: (format characters, comma-separated columns)}, `records` (name,
    values) in the order written (strings as str). Each message is 0xA3 0x95, its type id, its packed fields;
    FMT records (type 128: Type, Length, Name, Format, Columns) come first. Returns the records written."""
    ids = {name: 0x81 + i for i, name in enumerate(formats)}
    structs = {name: struct.Struct("<" + "".join(_STRUCT[c] for c in fmt)) for name, (fmt, _) in formats.items()}
    fmt_struct = struct.Struct("<BB4s16s64s")
    out = [HEAD + bytes([FMT_ID]) + fmt_struct.pack(FMT_ID, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns")]
    for name, (fmt, columns) in formats.items():
        out.append(HEAD + bytes([FMT_ID]) + fmt_struct.pack(ids[name], structs[name].size + 3, name.encode(),
                                                            fmt.encode(), columns.encode()))
    for name, values in records:
        packed = [v.encode() if isinstance(v, str) else v for v in values]
        out.append(HEAD + bytes([ids[name]]) + structs[name].pack(*packed))
    with open(path, "wb") as stream:
        stream.write(b"".join(out))
    return len(records)


# The formats of ArduPilot 4.x (AP_InertialSensor, AP_Logger LogStructure.h) that a session log needs.
FORMATS_4X = {
    "PARM": ("QNf", "TimeUS,Name,Value"),
    "IMU": ("QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "ARM": ("QBIBB", "TimeUS,ArmState,ArmChecks,Forced,Method"),
    "EV": ("QB", "TimeUS,Id"),
}


# ArduPilot before 4.0: one message type per instance (IMU, IMU2, IMU3), no instance field.
FORMATS_3X = {
    "PARM": ("QNf", "TimeUS,Name,Value"),
    **{name: ("QffffffIIfBBHH", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
       for name in ("IMU", "IMU2", "IMU3")},
    "ARM": ("QBIBB", "TimeUS,ArmState,ArmChecks,Forced,Method"),
    "EV": ("QB", "TimeUS,Id"),
}


def parameter_records(time_us: int, parameters: dict[str, float]) -> list[Record]:
    """PARM records, as AP_Logger writes the parameters at the start of a log."""
    return [("PARM", (int(time_us), name, float(value))) for name, value in parameters.items()]


def imu_records_3x(t_us: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray, temperature_degc: np.ndarray,
                   instance: int = 0) -> list[Record]:
    """IMU/IMU2/IMU3 records of one instance in the FORMATS_3X layout."""
    name = ("IMU", "IMU2", "IMU3")[instance]
    return [(name, (int(t), *map(float, g), *map(float, a), 0, 0, float(c), 1, 1, 1000, 1000))
            for t, a, g, c in zip(t_us.tolist(), accel_mps2, gyro_radps, temperature_degc)]


def imu_records(t_us: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray, temperature_degc: np.ndarray,
                instance: int = 0) -> list[Record]:
    """IMU records of one instance in the FORMATS_4X layout."""
    return [("IMU", (int(t), instance, *map(float, g), *map(float, a), 0, 0, float(c), 1, 1, 1000, 1000))
            for t, a, g, c in zip(t_us.tolist(), accel_mps2, gyro_radps, temperature_degc)]
