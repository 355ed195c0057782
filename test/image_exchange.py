"""Run as a process by test_dds_profile: ``receive N`` counts 640 x 480 rgb8 images on
``image`` (best effort, a history deep enough that a slow reader loses nothing) and prints the
count once N arrived or 20 s after the first one; ``send N`` waits for that reader, then
publishes N images at 30 Hz (best effort, as camera drivers publish)."""
import sys
import time

import numpy as np
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

BEST_EFFORT = QoSProfile(depth=64, reliability=ReliabilityPolicy.BEST_EFFORT)


def receive(node, n):
    received, first = [], []

    def on_image(msg):
        received.append(msg.header.stamp.sec)
        if not first:
            first.append(time.time())
    node.create_subscription(Image, 'image', on_image, BEST_EFFORT)
    print('ready', flush=True)
    while len(received) < n and (not first or time.time() - first[0] < 20):
        rclpy.spin_once(node, timeout_sec=0.1)
    print('received', len(set(received)), flush=True)


def send(node, n):
    pub = node.create_publisher(Image, 'image', BEST_EFFORT)
    while pub.get_subscription_count() < 1:
        rclpy.spin_once(node, timeout_sec=0.1)
    time.sleep(1.0)                  # discovery of the reader's locators settles
    msg = Image(height=480, width=640, encoding='rgb8', step=1920)
    msg.data = np.random.default_rng(0).integers(0, 256, 480 * 1920, np.uint8).tobytes()
    start = time.monotonic()
    for k in range(n):
        time.sleep(max(0.0, start + k / 30 - time.monotonic()))
        msg.header.stamp.sec = k
        pub.publish(msg)
    print('sent', n, flush=True)


if __name__ == '__main__':
    rclpy.init()
    node = rclpy.create_node(f'image_{sys.argv[1]}')
    {'receive': receive, 'send': send}[sys.argv[1]](node, int(sys.argv[2]))
    rclpy.shutdown()
