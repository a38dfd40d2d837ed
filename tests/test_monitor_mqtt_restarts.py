"""`jmlgdsl monitor` through broker restarts: mosquitto (saving its sessions when stopped) is stopped
and started again five times while a plant publishes the dryer recording at QoS 1. Like a
store-and-forward gateway (and like an MQTT library's publishes made while it reconnects, which go out
ahead of the messages it sends again), the plant keeps what it reads while cut off and sends it after
the readings of the moment it is back: one after the first restart, two after the second, and so
on, so the monitor sees the stream held ahead of it and then caught up with, and the stream moved on
and then filled in behind. The monitor holds its rows back while it is disconnected and
catching up, so every reading that arrived is diagnosed in its row, and the store exports the very
table `jmlgdsl run -o` writes for the recording."""

import threading
import time

import pytest
from monitor_servers import MOSQUITTO, NO_MOSQUITTO, WAIT, exported, expected_table, query, samples, stop, until
from test_monitor_mqtt import connected, monitor, stored

paho = pytest.importorskip("paho.mqtt.client")
pytestmark = pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)

RESTARTS = 5


class Plant:
    """A publisher of payloads to `dryer` at QoS 1, one every `pace` seconds, in a thread. While its
    connection is down it keeps them; once back for the k-th time, it sends the k payloads of the
    moment, then those it kept. Its MQTT library reconnects by itself and sends again what the broker
    had not acknowledged."""

    def __init__(self, port, payloads, pace):
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="plant")
        self.client.reconnect_delay_set(1, 1)
        self.up = threading.Event()
        self.client.on_connect = lambda client, userdata, flags, reason, properties: self.up.set()
        self.connections = 0  # the connections since the first
        self.moment = 0  # payloads of the moment sent since it was last back
        self.client.on_disconnect = lambda client, userdata, flags, reason, properties: self.up.clear()
        self.acknowledged = set()  # the mids the broker acknowledged
        self.client.on_publish = lambda client, userdata, mid, reason, properties: self.acknowledged.add(mid)
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        assert self.up.wait(WAIT), "the plant did not connect"
        self.sent, self.kept = [], []
        self.thread = threading.Thread(target=self._publish, args=(payloads, pace))
        self.thread.start()

    def _publish(self, payloads, pace):
        for payload in payloads:
            if not self.up.is_set():
                if not self.kept:
                    self.connections, self.moment = self.connections + 1, 0
                self.kept.append(payload)
            elif self.kept and self.moment < self.connections:
                self.send([payload])
                self.moment += 1
            else:
                self.send(self.kept + [payload])
                self.kept = []
            time.sleep(pace)

    def send(self, payloads):
        for payload in payloads:
            self.sent.append(self.client.publish("dryer", payload, qos=1).mid)

    def finish(self):
        """Wait until every payload is published and acknowledged by the broker, then disconnect."""
        self.thread.join(WAIT)
        deadline = time.monotonic() + WAIT
        try:
            while self.kept or not self.acknowledged.issuperset(self.sent):
                assert time.monotonic() < deadline, "the broker did not acknowledge every message"
                if self.kept and self.up.is_set():
                    self.send(self.kept)
                    self.kept = []
                time.sleep(0.02)
        finally:
            self.client.disconnect()
            self.client.loop_stop()


def events(store, kind):
    return query(store, f"SELECT count(*) FROM event WHERE kind = '{kind}'") or 0


def test_rows_wait_for_readings_sent_after_broker_restarts(broker, tmp_path):
    """After the third restart the monitor is killed with SIGKILL once the stream has moved on ahead of
    what the plant kept, with rows held for it, and started again: nothing it held is lost."""
    port, store = broker(persistent=True), str(tmp_path / "dryer.db")
    messages = samples()
    processes = [monitor(port, store)]
    try:
        until(connected(store), "the monitor to connect", processes[-1])
        plant = Plant(port, messages, 0.01)
        for restart in range(1, RESTARTS + 1):
            until(lambda: len(plant.sent) >= restart * len(messages) // (RESTARTS + 1), "the plant to publish",
                  processes[-1])
            broker.stop(port)
            until(lambda: events(store, "disconnect") >= restart, "the lost connection", processes[-1])
            broker(port=port, persistent=True)
            until(connected(store, restart + len(processes)), "the monitor to connect again", processes[-1])
            if restart == 3:
                until(lambda: events(store, "jump") == 1, "the stream to move on ahead of what was kept",
                      processes[-1])
                processes[-1].kill()
                processes[-1].wait(WAIT)
                processes.append(monitor(port, store))
                until(connected(store, restart + len(processes)), "the restarted monitor to connect", processes[-1])
        plant.finish()
        until(stored(store, 1000), "every row stored", processes[-1])
        stop(processes[-1])
    finally:
        for process in processes:
            process.kill()
    assert exported(tmp_path, store) == expected_table(tmp_path)
    assert query(store, "SELECT count(*) FROM sample") == 1000
    assert events(store, "gap") == 0
