// SPDX-License-Identifier: GPL-3.0-or-later
//
// Flamenco 3 job type: capture a Blender scene as a NeRF dataset on the farm.
// One task per shard runs
//     {blender} {blenderArgs} SCENE.blend --python NERF_BRIDGE/scripts/capture.py -- --out DATASET ... --shard K/N
// and a last task, once every shard has finished, runs the same script with --merge, which checks
// every planned frame and writes the dataset's transforms files, point cloud and manifest.
//
// Install: copy this file into the `scripts` folder next to the flamenco-manager executable and
// restart the Manager. Workers need the nerf-blender checkout (NERF_BRIDGE) and the dataset folder
// on shared storage, at the paths given below (use Flamenco variables for mixed platforms).
// Untested against a running Flamenco (none was available while writing it); see README.md.

const JOB_TYPE = {
    label: "NeRF Capture (sharded)",
    description: "Render a NeRF dataset with scripts/capture.py in N shards, then merge them",
    settings: [
        // Filled in by the Flamenco add-on when submitting from Blender.
        { key: "blendfile", type: "string", required: true, visible: "web",
          description: "Path of the .blend file to capture" },
        { key: "nerf_bridge_dir", type: "string", subtype: "dir_path", required: true, visible: "submission",
          description: "Folder of the nerf-blender checkout, as the Workers see it (holds scripts/capture.py)" },
        { key: "dataset_dir", type: "string", subtype: "dir_path", required: true, visible: "submission",
          description: "Dataset folder every shard writes into (shared storage; empty or a capture to resume)" },
        { key: "shards", type: "int32", default: 8, visible: "submission",
          description: "Number of shards (tasks) the frames are divided into" },
        { key: "capture_args", type: "string", visible: "submission",
          default: "--count 100 --val-count 10 --test-count 20 --resolution 200 --engine cycles --samples 64 --seed 0",
          description: "Other scripts/capture.py options, identical for every shard (space-separated)" },
    ]
};

function compileJob(job) {
    const settings = job.settings;
    const shards = settings.shards;
    if (!Number.isInteger(shards) || shards < 1) {
        throw "shards: must be a whole number of at least 1, got " + shards;
    }
    const extra = (settings.capture_args || "").trim().split(/\s+/).filter((a) => a.length > 0);
    for (const forbidden of ["--shard", "--merge", "--overwrite", "--out"]) {
        if (extra.some((a) => a === forbidden || a.startsWith(forbidden + "="))) {
            throw "capture_args: " + forbidden + " is set by the job type itself; remove it";
        }
    }
    const script = path.join(settings.nerf_bridge_dir, "scripts", "capture.py");
    const out = settings.dataset_dir;

    const shardTasks = [];
    for (let k = 1; k <= shards; k++) {
        const task = author.Task(`capture-shard-${k}-of-${shards}`, "blender");
        task.addCommand(author.Command("blender-render", {
            exe: "{blender}",
            exeArgs: "{blenderArgs}",
            argsBefore: [],
            blendfile: settings.blendfile,
            args: ["--python", script, "--", "--out", out, "--quiet"].concat(extra, ["--shard", `${k}/${shards}`]),
        }));
        job.addTask(task);
        shardTasks.push(task);
    }

    const merge = author.Task("merge-shards", "blender");
    merge.addCommand(author.Command("blender-render", {
        exe: "{blender}",
        exeArgs: "{blenderArgs}",
        argsBefore: [],
        blendfile: settings.blendfile,  // opened but unused: the merge reads the plan from the shards
        args: ["--python", script, "--", "--out", out, "--merge"],
    }));
    for (const task of shardTasks) {
        merge.addDependency(task);
    }
    job.addTask(merge);
}
