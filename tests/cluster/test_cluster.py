"""The dask helper: scheduler addresses, worker counts, results in job order, errors raised."""
import pytest

from incipient_slip.cluster import as_done, check_scheduler, check_workers, map_tasks
from incipient_slip.errors import UsageError


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:8786", "tcp://cluster.example.org:8786", "tls://10.0.0.2:8786",
                                     "inproc://10.0.0.2/4242/1"])
def test_scheduler_addresses_that_read_tcp_host_port_pass(address):
    assert check_scheduler(address) == address


@pytest.mark.parametrize("address", ["localhost:8786", "tcp://host", "tcp://:8786", "tcp://host:port",
                                     "http://host:8786", "tcp://host:8786/x", "inproc://", ""])
def test_other_scheduler_addresses_are_one_line_usage_errors(address):
    with pytest.raises(UsageError, match=r"expected tcp://host:port"):
        check_scheduler(address)


def test_worker_count_below_one_is_a_usage_error():
    assert check_workers(3) == 3 and check_workers(None) >= 1
    with pytest.raises(UsageError, match="--workers must be >= 1, got 0"):
        check_workers(0)


def test_tasks_return_in_job_order_and_a_task_error_is_raised(dask_client):
    # a function the workers can import (a test module is not on their path)
    from operator import floordiv
    client = dask_client(2)
    assert map_tasks(client, floordiv, [(100, x) for x in range(1, 8)], desc="t", progress=False) == \
        [100 // x for x in range(1, 8)]
    with pytest.raises(ZeroDivisionError):
        list(as_done(client, floordiv, [(1, 1), (1, 0)], desc="t", progress=False))
