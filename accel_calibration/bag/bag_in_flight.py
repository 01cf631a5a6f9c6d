"""What a flight recorded as a rosbag2 (sqlite3 or mcap) says of its IMU in flight, beside its still moments on
the ground (flight_evidence_bag.py), as in_flight_evidence.py says it of an autopilot log: JSON-ready dicts,
{"reason": ...} where the bag gives none.

- **Agreement with its siblings**: a bag that records several sensor_msgs/msg/Imu topics (a vehicle with two or
  three IMUs) in flight. Each topic's per-second means in flight (imu_agreement.SecondSums; the bag streamed a
  group of messages at a time, as replay reads it), then imu_agreement.agreement over the topics; each topic is
  named by itself. The calibration in force (`fleet --calibration`) is applied to the topic replayed, the
  others are taken as recorded (the JSON's `in_force` says so).
- **The filter's settled bias**: PX4 through uXRCE-DDS publishes `/fmu/out/estimator_sensor_bias`
  (px4_msgs/msg/EstimatorSensorBias, the ULog topic's fields), decoded with the definition the bag records
  (rosbags' reader registers it) and settled as a ULog's (estimator_bias.px4_settled). A bag's Imu topic names
  no device: the estimate is of the device the filter names (`device`; where it names several, the one it
  estimated longest).

The flight state is the bag's (flight_sources.bag_flight_state: `--armed-topic`, else the known topics), the
same the replay used."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import AccelCalibrationError
from .in_flight_evidence import Said, _clean

ESTIMATOR_TYPE = "px4_msgs/msg/EstimatorSensorBias"
ESTIMATOR_TOPIC = "/fmu/out/estimator_sensor_bias"
# The fields of EstimatorSensorBias.msg read, as arrays of three or one value per message.
_TRIPLES = ("accel_bias", "accel_bias_variance", "gyro_bias", "gyro_bias_variance")
_SCALARS = ("accel_device_id", "accel_bias_valid", "accel_bias_stable", "gyro_device_id", "gyro_bias_valid",
            "gyro_bias_stable")


def bag_in_flight(path: str | os.PathLike[str], imu_topic: str, calibration: Any = None, calibration_name: str = "",
                  armed_topic: str | None = None, armed_field: str | None = None,
                  temperature_topic: str | None = None) -> tuple[Said, Said]:
    """(estimator, agreement) of the bag's IMU on `imu_topic` (the topic replayed), `calibration` (a
    core.calibration.Calibration, named `calibration_name`) its calibration in force; never raises for what
    the bag lacks: the reason says it."""
    from .flight_sources import bag_flight_state
    from .in_flight_evidence import _no_flight

    name = Path(path).name
    try:
        flight_state = bag_flight_state(path, armed_topic, armed_field)
        topics = _imu_topics(path)
    except AccelCalibrationError as error:
        reason = {"reason": str(error)}
        return reason, reason
    no_flight = _no_flight(name, flight_state)
    if no_flight is not None:
        no_flight = no_flight.replace("in the log", "in the bag")
        return {"reason": no_flight}, {"reason": no_flight}
    return (_estimator(path, flight_state),
            _agreement(path, imu_topic, topics, flight_state, calibration, calibration_name, temperature_topic))


def _imu_topics(path: str | os.PathLike[str]) -> list[str]:
    """The bag's sensor_msgs/msg/Imu topics, in the order it lists them."""
    from .bag_io import IMU, metadata_topics
    from .recording import _file_topics

    infos = metadata_topics(path) if Path(path).is_dir() else _file_topics(path)
    if infos is None:  # a directory whose metadata.yaml lists nothing readable: rosbags' reader
        from .bag_io import open_reader

        reader = open_reader(path)
        try:
            return [c.topic for c in reader.connections if c.msgtype == IMU]
        finally:
            reader.close()
    return list(dict.fromkeys(info.topic for info in infos if info.msgtype == IMU))


# ---------------------------------------------------------------------------------------------- agreement
def _agreement(path: str | os.PathLike[str], imu_topic: str, topics: list[str], flight_state: Any,
               calibration: Any, calibration_name: str, temperature_topic: str | None) -> Said:
    from .imu_agreement import agreement

    name = Path(path).name
    if len(topics) < 2:
        return {"reason": f"{name}: the bag records one Imu topic ({imu_topic}): no sibling to compare with"}
    if imu_topic not in topics:
        return {"reason": f"{name}: {imu_topic} is not among the bag's Imu topics ({', '.join(topics)})"}
    means = {}
    for k, topic in enumerate(topics):
        try:
            means[k] = _topic_means(path, topic, flight_state, calibration if topic == imu_topic else None,
                                    temperature_topic if topic == imu_topic else None)
        except AccelCalibrationError as error:
            return {"reason": f"{name}: cannot read {topic} for the agreement ({error})"}
        except Exception as error:  # noqa: BLE001 - a damaged storage makes the readers raise their own types
            return {"reason": f"{name}: cannot read {topic} for the agreement ({_first_line(error)})"}
    try:
        said = agreement(means)[topics.index(imu_topic)]
    except (np.linalg.LinAlgError, ValueError) as error:  # degenerate seconds (a dead IMU's zeros): its reason
        return {"reason": f"{name}: agreement not measurable ({error})"}
    if isinstance(said, str):
        return {"reason": f"{name}: {said}"}
    in_force = f"{calibration_name} (calibration file)" if calibration is not None else "as recorded"
    return {**_clean(said.as_json()), "in_force": f"{imu_topic} {in_force}; its siblings as recorded"}


def _topic_means(path: str | os.PathLike[str], topic: str, flight_state: Any, calibration: Any,
                 temperature_topic: str | None) -> Any:
    """One Imu topic's per-second means in flight (imu_agreement.FlightMeans, named by the topic), `calibration`
    applied to each sample; the bag streamed a group at a time where its storage allows, else read whole."""
    from .estimator_bias import in_flight
    from .imu_agreement import FlightMeans, SecondSums
    from .mcap_scan import DamagedChunk, NotStreamable
    from .recording import open_recording, stream_bag

    def summed(pieces: Any) -> tuple[SecondSums, SecondSums]:
        accel_sums, gyro_sums = SecondSums(), SecondSums()
        for t_ns, accel, gyro in pieces:
            flying = in_flight(t_ns, flight_state)
            if calibration is not None:
                accel = calibration.apply(accel)
                gyro = calibration.apply_gyro(gyro)
            accel_sums.add(t_ns, accel, flying)
            gyro_sums.add(t_ns, gyro, flying)
        return accel_sums, gyro_sums

    try:
        try:
            bag = stream_bag(path, imu_topic=topic, temperature_topic=temperature_topic)
            if bag is None:
                raise NotStreamable("not streamable")
            accel_sums, gyro_sums = summed(imu for imu, _ in bag.pieces() if imu is not None)
        except NotStreamable:  # read whole: what streaming could not give, or the reason
            recording = open_recording(path, imu_topic=topic, temperature_topic=temperature_topic)
            gyro = recording.gyro_radps if recording.gyro_radps is not None else np.full_like(recording.accel_mps2,
                                                                                            np.nan)
            accel_sums, gyro_sums = summed([(recording.t_ns, recording.accel_mps2, gyro)])
    except DamagedChunk as error:
        raise AccelCalibrationError(f"damaged mcap file {error}") from None
    blocks, accel = accel_sums.means()
    gyro_blocks, rates = gyro_sums.means()
    return FlightMeans(topic, blocks, accel, rates if np.array_equal(blocks, gyro_blocks) else None)


# ---------------------------------------------------------------------------------------------- estimator
def _estimator(path: str | os.PathLike[str], flight_state: Any) -> Said:
    from .bag_io import open_reader, recorded_definitions
    from .estimator_bias import px4_settled

    name = Path(path).name
    no_topic = {"reason": f"{name}: the bag records no estimator_sensor_bias (the filter's bias estimates: "
                          f"{ESTIMATOR_TYPE}, e.g. {ESTIMATOR_TOPIC})"}
    recorded = recorded_definitions(path)  # the storage's own list: no rosbags reader to open where it is absent
    if recorded is not None and not any(msgtype == ESTIMATOR_TYPE for msgtype, _, _ in recorded.values()):
        return no_topic
    try:
        reader = open_reader(path)
    except AccelCalibrationError as error:
        return {"reason": str(error)}
    try:
        connections = [c for c in reader.connections if c.msgtype == ESTIMATOR_TYPE]
        if not connections:
            return no_topic
        datasets = [_columns(reader, connection, name) for connection in connections]
    except AccelCalibrationError as error:
        return {"reason": str(error)}
    except Exception as error:  # noqa: BLE001 - a damaged storage makes the readers raise their own types
        return {"reason": f"{name}: cannot read {ESTIMATOR_TOPIC} ({_first_line(error)})"}
    finally:
        reader.close()
    found = px4_settled(datasets, flight_state, name)
    if isinstance(found, str):
        return {"reason": found}
    device, bias = max(found.items(), key=lambda item: item[1].samples)
    return {**_clean(bias.as_json()), "device": device, "topic": ", ".join(c.topic for c in connections)}


def _columns(reader: Any, connection: Any, name: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A topic of EstimatorSensorBias as (stamps ns, {field: array}) with the ULog's names (accel_bias[0], ...),
    decoded with the definition recorded in the bag."""
    from .flight_sources import _stamp_ns

    stamps: list[int] = []
    rows: dict[str, list[Any]] = {}
    for _, recorded_ns, raw in reader.messages(connections=[connection]):
        try:
            message = reader.deserialize(raw, connection.msgtype)
            values = {field: np.asarray(getattr(message, field), dtype=float) for field in _TRIPLES}
            values.update({field: getattr(message, field) for field in _SCALARS if hasattr(message, field)})
        except Exception as error:  # noqa: BLE001 - rosbags raises per cause; the bag is the problem
            first = str(error).splitlines()[0][:100] if str(error) else type(error).__name__
            raise AccelCalibrationError(f"{name}: cannot decode {connection.topic} ({connection.msgtype}) with the "
                                        f"definitions recorded in the bag ({first})") from None
        stamps.append(_stamp_ns(message, recorded_ns))
        for field, value in values.items():
            if field in _TRIPLES:
                for k in range(3):
                    rows.setdefault(f"{field}[{k}]", []).append(float(value[k]))
            else:
                rows.setdefault(field, []).append(value)
    return np.array(stamps, dtype=np.int64), {k: np.asarray(v) for k, v in rows.items()}


def _first_line(error: Exception) -> str:
    first = str(error).splitlines()[0][:100] if str(error) else ""
    return f"{type(error).__name__}: {first}" if first else type(error).__name__
