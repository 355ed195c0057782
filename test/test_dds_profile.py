"""config/fastdds_large_images.xml: Fast DDS loads it, and with it every 640 x 480 rgb8 image
(921,600 bytes) one process publishes at 30 Hz reaches another over shared memory (with Fast
DDS's 512 KB default segment about half were lost here: record 0616)."""
from pathlib import Path
import subprocess
import sys

import pytest

REPO = Path(__file__).resolve().parents[1]
PROFILE = REPO / 'config' / 'fastdds_large_images.xml'
SCRIPT = Path(__file__).resolve().parent / 'image_exchange.py'
IMAGES = 60


def test_shipped_profile_brings_every_large_image_across(ros_env):
    pytest.importorskip('rclpy')
    env = {**ros_env, 'FASTRTPS_DEFAULT_PROFILES_FILE': str(PROFILE)}
    reader = subprocess.Popen([sys.executable, str(SCRIPT), 'receive', str(IMAGES)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert reader.stdout.readline().strip() == 'ready'
        sender = subprocess.run([sys.executable, str(SCRIPT), 'send', str(IMAGES)], env=env,
                                capture_output=True, text=True, timeout=120)
        assert sender.stdout.strip() == f'sent {IMAGES}', sender.stdout + sender.stderr
        out, _ = reader.communicate(timeout=60)
    finally:
        reader.kill()
    assert 'Error' not in out and 'error' not in out, out      # the XML parsed
    assert out.strip().splitlines()[-1] == f'received {IMAGES}', out
