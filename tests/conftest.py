"""Test-session settings."""

from tqdm import tqdm

# tqdm starts a monitor thread with its first bar (even a disabled one) that wakes every 10 s
# and allocates; tracemalloc counts every thread, so a wake-up inside the allocation test's
# window (tests/test_estimator.py) looked like an estimator allocation.  No monitor here.
tqdm.monitor_interval = 0
