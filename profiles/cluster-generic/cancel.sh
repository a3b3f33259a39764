#!/usr/bin/env bash
# Stops jobs submit.sh started, each a process group ($@: job ids).
for id in "$@"; do
    kill -TERM -- "-$id" 2> /dev/null || true
done
