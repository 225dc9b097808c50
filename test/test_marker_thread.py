"""sim_node's marker thread: the latest job only, the waiting one run at close, errors said."""

import threading
import time

from pulsejet_sim.ros.state_publisher import LatestJobThread


def _blocking_job(ran, started, release, name):
    def job():
        started.set()
        release.wait(10)
        ran.append(name)

    return job


def test_a_job_handed_over_while_another_waits_replaces_it():
    ran, errors = [], []
    started, release = threading.Event(), threading.Event()
    worker = LatestJobThread('test', errors.append)
    worker.submit(_blocking_job(ran, started, release, 'first'))
    assert started.wait(10)
    worker.submit(lambda: ran.append('second'))  # replaced before it runs
    worker.submit(lambda: ran.append('third'))
    release.set()
    worker.close()
    assert ran == ['first', 'third'] and errors == []


def test_close_sends_the_job_still_waiting():
    ran = []
    started, release = threading.Event(), threading.Event()
    worker = LatestJobThread('test', print)
    worker.submit(_blocking_job(ran, started, release, 'first'))
    assert started.wait(10)
    worker.submit(lambda: ran.append('last'))
    closer = threading.Thread(target=worker.close, kwargs={'timeout_s': 10.0})
    closer.start()  # the stop request arrives while 'last' waits
    time.sleep(0.05)
    release.set()
    closer.join(15)
    assert ran == ['first', 'last']


def test_a_failing_job_is_reported_and_the_thread_goes_on():
    ran, errors = [], []
    worker = LatestJobThread('test', errors.append)

    def failing():
        raise RuntimeError('publisher gone')

    worker.submit(failing)
    end = time.monotonic() + 10
    while not errors and time.monotonic() < end:
        time.sleep(0.01)
    worker.submit(lambda: ran.append('after'))
    worker.close()
    assert errors == ['RuntimeError: publisher gone'] and ran == ['after']
