"""A python `canopen` master that reads and writes the objects of machlink's simulated
drives over SLCAN, and prints what it found as one JSON object.

    python3 canopen_master.py --port PATH --nodes 1,2,3
"""

import argparse
import json
import os
import sys
import time

import canopen

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from canopen_od import drive_od  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", required=True)
    ap.add_argument("--nodes", default="1,2,3")
    a = ap.parse_args()
    network = canopen.Network()
    network.connect(interface="slcan", channel=a.port, bitrate=1000000, sleep_after_open=0)
    result = {}
    try:
        for n in [int(x) for x in a.nodes.split(",")]:
            node = network.add_node(n, drive_od(n))
            node.sdo.RESPONSE_TIMEOUT = 5.0
            r = {}
            r["device_type"] = node.sdo.upload(0x1000, 0).hex()
            r["device_name"] = node.sdo[0x1008].raw  # segmented upload
            node.sdo[0x6060].raw = 8
            r["mode_display"] = node.sdo[0x6061].raw
            node.sdo[0x60C2][1].raw = 4
            r["ip_period"] = node.sdo[0x60C2][1].raw
            node.sdo[0x6040].raw = 0x0006  # shutdown
            r["statusword_after_shutdown"] = node.sdo[0x6041].raw
            node.sdo[0x6040].raw = 0x0007  # switch on
            r["statusword_after_switch_on"] = node.sdo[0x6041].raw
            try:
                node.sdo[0x6041].raw = 0
                r["write_statusword"] = "accepted"
            except canopen.SdoAbortedError as e:
                r["write_statusword"] = e.code
            try:
                node.sdo.upload(0x5FFF, 0)
                r["read_missing"] = "answered"
            except canopen.SdoAbortedError as e:
                r["read_missing"] = e.code
            # a segmented download: the drive refuses it (0x1008 is read-only) by name
            try:
                node.sdo.download(0x1008, 0, b"renamed by python canopen")
                r["write_name"] = "accepted"
            except canopen.SdoAbortedError as e:
                r["write_name"] = e.code
            node.sdo[0x1017].raw = 50
            node.nmt.state = "OPERATIONAL"
            node.nmt.wait_for_heartbeat(timeout=10)
            time.sleep(0.12)
            r["nmt_state"] = node.nmt.state
            result[str(n)] = r
    finally:
        network.disconnect()
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
