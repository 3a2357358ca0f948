//! The dashboard at `/` in a real browser: headless Chromium loads the page from a running
//! coordinator, runs its scripts against the REST API, and the resulting DOM shows the job (its
//! id, state and preview) and the worker that rendered it.
//!
//! Needs `chromium` (Debian's package; `.ci/run` installs it and sets
//! `RENDERFARM_BROWSER_TEST=required`). Without it the test says so and passes only when the
//! browser is not required.

use std::{process::Command, time::Duration};

use serde_json::json;
use tests::*;

fn chromium() -> Option<String> {
    ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .map(str::to_string)
        .find(|b| Command::new(b).arg("--version").output().is_ok_and(|o| o.status.success()))
}

/// The browser, or `None` (the test then passes, saying it was skipped) where there is none and
/// none is required (`RENDERFARM_BROWSER_TEST=required` fails the test instead).
fn browser() -> Option<String> {
    let found = chromium();
    if found.is_none() {
        let required = std::env::var("RENDERFARM_BROWSER_TEST").is_ok_and(|v| v == "required");
        assert!(!required, "no chromium found, but RENDERFARM_BROWSER_TEST=required");
        eprintln!("SKIPPED: no chromium on this machine (apt-get install chromium)");
    }
    found
}

#[test]
fn the_dashboard_shows_jobs_and_workers_in_a_real_browser() {
    let Some(browser) = browser() else { return };
    let dir = temp_dir("dashboard");
    let farm = Cluster::start(&dir, 1, &[]);
    let (url, scene) = (farm.url.clone(), farm.scene.clone());
    let id = create_job(&url, &scene, &json!({"width": 32, "height": 32, "spp": 8}), 3);
    wait_done(&url, &id, Duration::from_secs(120));
    let dom = dump(&browser, &dir, &url);
    let jobs = jobs_table(&dom);
    assert!(jobs.contains(&id), "the job {id} is not listed:\n{jobs}");
    assert!(jobs.contains("done"), "the job's state is not shown:\n{jobs}");
    assert!(jobs.contains("<img"), "no preview of the finished job:\n{jobs}");
    let workers = dom.split("id=\"workers-table\"").nth(1).expect("a workers table in the page");
    let workers = workers.split("</table>").next().unwrap();
    assert!(workers.contains("<td"), "no worker listed:\n{workers}");
    // Its row: name, threads, tasks and samples done, leases, failed, expired, last seen.
    let row = workers.split("<tbody>").nth(1).unwrap().split("</tr>").next().unwrap();
    assert_eq!(row.matches("<td").count(), 8, "the worker's health is not shown:\n{row}");
    assert!(dom.contains("id=\"upload-form\""), "no upload form");

    // Jobs come a page at a time, newest first: with pages of two, the newest two, then the
    // one before them through the API's cursor; a state filter shows only its jobs.
    // The newest has a name, shown as text in place of its id (the id on hover).
    let small = json!({"width": 8, "height": 8, "spp": 1});
    let named = json!({"scene": scene, "settings": small, "name": "<b>lobby</b> & co"});
    let a = post_json(&format!("{url}/api/v1/jobs"), &named);
    assert_eq!(a.status, 201, "{}", a.error());
    let more =
        vec![create_job(&url, &scene, &small, 0), a.json()["id"].as_str().unwrap().to_string()];
    for job in &more {
        wait_done(&url, job, Duration::from_secs(120));
    }
    let page = jobs_table(&dump(&browser, &dir, &format!("{url}/?jobs=2")));
    assert!(page.contains(&more[0]) && page.contains(&more[1]), "{page}");
    assert!(!page.contains(&id), "the oldest job is on the next page:\n{page}");
    assert!(page.contains("&lt;b&gt;lobby&lt;/b&gt; &amp; co"), "the name is not shown:\n{page}");
    assert!(page.contains(&format!("title=\"{}\"", more[1])), "no id on the name:\n{page}");
    let next = get(&format!("{url}/api/v1/jobs?order=newest&limit=2")).json()["next"].clone();
    let next = next.as_str().expect("a next page").to_string();
    let older = dump(&browser, &dir, &format!("{url}/?jobs=2&after={next}"));
    let page = jobs_table(&older);
    assert!(page.contains(&id) && !page.contains(&more[0]), "{page}");
    assert!(older.contains("older than the newest"), "the page does not say where it is");
    let failed = jobs_table(&dump(&browser, &dir, &format!("{url}/?state=failed")));
    assert!(failed.contains("No jobs on this page") && !failed.contains(&id), "{failed}");
}

/// The DOM of `url` after its scripts ran in headless Chromium.
fn dump(browser: &str, dir: &std::path::Path, url: &str) -> String {
    let output = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--virtual-time-budget=10000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", dir.join("profile").display()))
        .arg(url)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// The jobs table of a page's DOM.
fn jobs_table(dom: &str) -> String {
    let jobs = dom.split("id=\"jobs-table\"").nth(1).expect("a jobs table in the page");
    jobs.split("</table>").next().unwrap().to_string()
}

/// The frame view in a real browser: opened from the page's address on a two-frame job, it
/// shows the frame asked for through the tone map and exposure asked for, the error heat map
/// with one cell per tile, the error-against-time plot, and the frame browser.
#[test]
fn the_frame_view_shows_a_frame_its_tiles_and_its_error_in_a_real_browser() {
    let Some(browser) = browser() else { return };
    let dir = temp_dir("dashboard-frame-view");
    let farm = Cluster::start(&dir, 1, &[]);
    let (url, scene) = (farm.url.clone(), farm.scene.clone());
    let s = json!({"width": 32, "height": 32, "tile_size": 16, "spp": 16, "samples_per_task": 4,
                   "frames": {"start": 0, "end": 1, "fps": 24}});
    let id = create_job(&url, &scene, &s, 0);
    wait_done(&url, &id, Duration::from_secs(120));
    let dom =
        dump(&browser, &dir, &format!("{url}/?view={id}&frame=1&exposure=1.5&tonemap=aces&heat=1"));
    let view = dom.split("id=\"frame-view\"").nth(1).expect("a frame view in the page");
    let view = view.split("</section>").next().unwrap();
    assert!(view.starts_with('>'), "the frame view is hidden:\n{view}");
    assert!(view.contains(": frame 1<"), "not frame 1:\n{view}");
    let image = view.split("id=\"fv-image\"").nth(1).unwrap().split('>').next().unwrap();
    assert!(image.contains("data-query=\"frames/1.png?exposure=1.5&amp;tonemap=aces\""), "{image}");
    assert!(image.contains("data-loaded=\"1\""), "the image did not load: {image}");
    let heat = view.split("id=\"fv-heatmap\"").nth(1).unwrap().split("</svg>").next().unwrap();
    assert_eq!(heat.matches("<rect").count(), 4, "one cell per tile:\n{heat}");
    assert!(heat.contains("16 spp (4 of 4 tasks)"), "{heat}");
    assert!(!heat.split('>').next().unwrap().contains("display: none"), "the heat map is hidden");
    let plot = view.split("id=\"fv-plot\"").nth(1).unwrap().split("</svg>").next().unwrap();
    let points: usize =
        plot.split("data-points=\"").nth(1).unwrap().split('"').next().unwrap().parse().unwrap();
    // A point at least (the job took less than the history's first step), each marked.
    assert!(points >= 1 && plot.contains("id=\"fv-error-line\""), "no error line:\n{plot}");
    assert_eq!(plot.matches("<circle").count(), points, "{plot}");
    let frames = view.split("id=\"fv-frame\"").nth(1).unwrap().split("</select>").next().unwrap();
    assert_eq!(frames.matches("<option").count(), 2, "{frames}");
}
