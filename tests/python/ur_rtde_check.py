#!/usr/bin/env python3
"""Drive `rig-mock ur5e` with PyPI ur-rtde, a client no one on this project wrote.

Run by tests/ur_rtde_interop.rs. ur_rtde's interfaces use port 30004 only (hard-coded), so
the mock must listen there. The script

1. streams with RTDEReceiveInterface (default frequency: 500 Hz on an e-Series controller
   version) for --seconds, recording every distinct `timestamp`;
2. reads the actual TCP pose, robot mode and safety mode;
3. writes --value into input_int_register_<--register> with RTDEIOInterface
   (ur_rtde allows registers 18..22 by default);

and prints one JSON object on stdout for the Rust test to assert on. It does not judge the
values itself, so a failure shows the numbers.
"""

import argparse
import json
import sys
import time


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--register", type=int, default=18)
    ap.add_argument("--value", type=int, default=424242)
    args = ap.parse_args()

    try:
        import rtde_io
        import rtde_receive
    except ImportError as e:
        print(json.dumps({"error": f"python module ur_rtde missing ({e}): pip install ur-rtde==1.6.5"}))
        return 2

    recv = rtde_receive.RTDEReceiveInterface(args.host)
    stamps = []
    last = None
    t_end = time.monotonic() + args.seconds
    # Poll as fast as Python can: ur_rtde's receive thread updates the state at the stream rate,
    # and every distinct timestamp seen is one data package.
    while time.monotonic() < t_end:
        ts = recv.getTimestamp()
        if ts != last:
            stamps.append(ts)
            last = ts
    pose = list(recv.getActualTCPPose())
    robot_mode = recv.getRobotMode()
    safety_mode = recv.getSafetyMode()
    connected = recv.isConnected()
    recv.disconnect()

    io = rtde_io.RTDEIOInterface(args.host)
    set_ok = io.setInputIntRegister(args.register, args.value)
    # Give the package time to leave before the socket closes.
    time.sleep(0.2)
    io.disconnect()

    steps = [b - a for a, b in zip(stamps, stamps[1:])]
    good_steps = sum(1 for s in steps if abs(s - 0.002) < 1e-6)
    # A poller can miss packages when several arrive at once (the latest-state slot is
    # overwritten), so also count steps that are whole multiples of the 2 ms period.
    on_grid = sum(1 for s in steps if s > 0 and abs(s / 0.002 - round(s / 0.002)) < 1e-3)
    print(
        json.dumps(
            {
                "distinct_timestamps": len(stamps),
                "steps": len(steps),
                "steps_of_2ms": good_steps,
                "steps_on_2ms_grid": on_grid,
                "first_timestamp": stamps[0] if stamps else None,
                "last_timestamp": stamps[-1] if stamps else None,
                "max_step": max(steps) if steps else None,
                "min_step": min(steps) if steps else None,
                "actual_tcp_pose": pose,
                "robot_mode": robot_mode,
                "safety_mode": safety_mode,
                "connected_while_streaming": connected,
                "set_input_int_register": set_ok,
                "register": args.register,
                "value": args.value,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
