"""MQTT publication to the plant's broker: state, results, alarms and calibration version under an
ISA-95 topic tree, QoS 1, through a durable bounded outbox (docs/mqtt.md).

- :mod:`~cellctl.mqtt.topics`: the topic tree (the one definition the docs render);
- :mod:`~cellctl.mqtt.payloads`: the JSON payloads and their envelope;
- :mod:`~cellctl.mqtt.outbox`: queueing into the store's outbox (:mod:`cellctl.store.outbox`);
- :mod:`~cellctl.mqtt.bridge`: the cell's events into the outbox;
- :mod:`~cellctl.mqtt.publisher`: the connection and the outbox's drain;
- :mod:`~cellctl.mqtt.publication`: all of it for one cell, as the service starts and stops it.

It imports neither the twin nor a driver (import contracts in pyproject.toml).
"""

from cellctl.mqtt.publication import MqttPublication, MqttSetupError
from cellctl.mqtt.topics import TOPICS, CellTopics

__all__ = ["TOPICS", "CellTopics", "MqttPublication", "MqttSetupError"]
