#!/usr/bin/env bash
# Stand-in for a batch system's submit command, for trying the cluster profile on one
# machine: runs the jobscript Snakemake hands over ($1) in the background, in a process
# group of its own (so cancel.sh can stop it with everything it started), and prints the
# job id (that process group). Logs and exit statuses go to logs/cluster/ID.{log,rc},
# along with the job's properties as Snakemake wrote them (rule or group, resources).
set -euo pipefail
jobscript=$1
mkdir -p logs/cluster
set -m
bash -c 'id=$$
sed -n "s/^# properties = //p" "$1" > "logs/cluster/$id.json"
bash "$1" > "logs/cluster/$id.log" 2>&1
echo $? > "logs/cluster/$id.rc.tmp" && mv "logs/cluster/$id.rc.tmp" "logs/cluster/$id.rc"' \
    job "$jobscript" < /dev/null > /dev/null 2>&1 &
echo $!
