"""Live audio: capture and playback through PortAudio, and the two voices on the run's time line.

- ``ring``: the sample rings between PortAudio callbacks and threads (never blocking a callback);
- ``playback``: the self voice's output stream, which knows how much has left the speaker;
- ``self_voice``: where the self voice comes from (file, stdin, socket); ``feeder``: the thread
  that keeps it queued ahead of the speaker;
- ``capture``: the partner's microphone (or a file played as one), with capture times;
- ``assembler``: both voices on one time line, chunked for the generator;
- ``devices``: finding and listing devices; ``timeline``: one voice at the analysis rate.

The clock that reads the playback position is ``convodrive.scheduler.clock.PlaybackClock``; the
run that wires all of it is ``convodrive.pipeline.session`` (``convodrive live`` runs one).
"""
