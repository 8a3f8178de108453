# Copyright 2026 The mlsemreg_ros Authors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""``mlsemreg play``'s run: rclpy up, a node, the :class:`~mlsemreg_ros.ros.player.Player`."""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.ros.player import PlayOptions


def play_bag(bag: Path, options: PlayOptions) -> int:
    """Play ``bag`` on a node of its own; return the exit code (130 when interrupted)."""
    from mlsemreg_ros.ros.player import Player
    import rclpy

    rclpy.init()
    player = None
    try:
        node = rclpy.create_node('mlsemreg_player')
        player = Player(node, bag, options)
        player.run()
    except KeyboardInterrupt:
        return 130
    finally:
        if player is not None:
            player.close()
        rclpy.try_shutdown()
    return 0
