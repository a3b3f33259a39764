#!/usr/bin/env bash
# Status of a job submit.sh started ($1): running while its process lives, then success or
# failed from its exit status; failed when it vanished without one (killed).
if kill -0 "$1" 2> /dev/null; then
    echo running
elif [[ -f logs/cluster/$1.rc ]]; then
    [[ $(< "logs/cluster/$1.rc") == 0 ]] && echo success || echo failed
else
    echo failed
fi
