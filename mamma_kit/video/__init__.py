"""Video and audio I/O through PyAV: exact timestamps (VFR), audio on the video's time
origin, tmcd timecode, and an H.264 + AAC/PCM writer."""

from mamma_kit.video.audio import Audio, has_audio, read_audio
from mamma_kit.video.reader import VideoInfo, VideoReader, probe, read_timecode
from mamma_kit.video.writer import VideoWriter, write_video

__all__ = ["Audio", "has_audio", "read_audio", "VideoInfo", "VideoReader", "probe", "read_timecode",
           "VideoWriter", "write_video"]
