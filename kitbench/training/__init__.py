"""What `lerobot-train` reads from a kitbench dataset, served from memory.

Stock `LeRobotDataset` spends ~10 ms of a loader worker on each training sample of a camera dataset: half of it
in `datasets` row reads (every column read deep-copies the table's feature objects), the rest decoding the frame
and shifting it. `reader.FastReader` gives the same samples, bit for bit, from the table's columns held as numpy
arrays (`columns.Columns`) and every frame decoded once, by lerobot's own decoders, into a memory-mapped cache
(`frames.FrameCache`). The LeRobot plugin installs it (`reader.install`), so training stays `lerobot-train
--config_path=...`; figures and the reasons in docs/training-input.md. The plugin also has `lerobot-train` flush
denormal floats to zero (`denormals`): Adam's state of weights that never get a gradient decays into them.
"""
