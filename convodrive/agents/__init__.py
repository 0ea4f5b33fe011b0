"""Adapters from voice-agent frameworks to a ``LiveSession`` (``convodrive.pipeline.session``):
``pipecat`` (``pip install 'convodrive[pipecat]'``) and ``livekit`` (``pip install
'convodrive[livekit]'``). Each imports its framework, so import the one you use; nothing else in
convodrive imports them."""
