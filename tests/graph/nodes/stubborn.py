"""Test node: ignores SIGINT and SIGTERM (only SIGKILL ends it); announced in the graph."""
import signal
import time

from incipient_slip.graph.runtime import Node

if __name__ == "__main__":
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_IGN)
    node = Node("stubborn", heartbeat_s=0)
    while True:
        time.sleep(1)
