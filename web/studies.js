// The study browser: search the PACS through the server (the browser never
// talks to the PACS), list a study's series, open one (the server fetches
// and bricks it; a progress bar follows), and IHE Invoke Image Display
// requests (`#iid=…`, where GET /IHEInvokeImageDisplay sends the browser).

import { authFetch } from './auth.js';

// How often an opening series is looked at, ms.
const POLL_MS = 400;

// The answer of GET `path` as JSON, or an Error with the server's words.
async function getJson(path, init = {}) {
  const response = await authFetch(path, init);
  const body = await response.json().catch(() => ({}));
  if (!response.ok) {
    const error = new Error(body.error || `${path.split('?')[0]} answered HTTP ${response.status}`);
    error.status = response.status;
    throw error;
  }
  return body;
}

// A DICOM person name (family^given^middle^prefix^suffix) as people write it.
export function personName(pn) {
  const [family = '', given = '', middle = '', prefix = '', suffix = ''] = pn.split('=')[0].split('^');
  const first = [prefix, given, middle].filter(Boolean).join(' ');
  return [family, first].filter(Boolean).join(', ') + (suffix ? ` ${suffix}` : '');
}

// A DICOM date (YYYYMMDD) as ISO 8601, unambiguous in every country.
export function isoDate(da) {
  return /^\d{8}$/.test(da) ? `${da.slice(0, 4)}-${da.slice(4, 6)}-${da.slice(6)}` : da;
}

// How far opening a series has come, 0 to 1, and in words.
function progressOf(job) {
  if (job.state === 'ready') return [1, 'Ready'];
  if (job.state === 'bricking') {
    const f = job.slices ? job.bricked / job.slices : 0;
    return [0.5 + 0.5 * f, `Preparing the volume: ${Math.round(100 * f)}%`];
  }
  const f = job.total ? job.fetched / job.total : 0;
  const mb = (job.bytes / 1e6).toFixed(0);
  return [0.5 * f, job.total ? `Fetching images from the PACS: ${job.fetched} of ${job.total} (${mb} MB)` : 'Asking the PACS for the series…'];
}

export class StudyBrowser {
  // `panel` is the toolbar's Studies panel; `onOpened(id, how)` shows
  // dataset `id` once the server offers it (`how.preview`: a sample of the
  // series while the rest arrives; `how.again`: the whole series in place
  // of its preview); `onProgress(fraction, words)` (or null when done)
  // shows how opening goes over the page, `onPreviewProgress` the same
  // while a preview is shown.
  constructor(panel, { onOpened, onProgress, onPreviewProgress }) {
    this.panel = panel;
    this.onOpened = onOpened;
    this.onProgress = onProgress;
    this.onPreviewProgress = onPreviewProgress;
    this.pacs = [];
    this.form = panel.querySelector('form');
    this.studyList = panel.querySelector('#study-list');
    this.seriesList = panel.querySelector('#series-list');
    this.message = panel.querySelector('#studies-message');
    this.form.addEventListener('submit', (e) => {
      e.preventDefault();
      this.search();
    });
  }

  // Shows the panel if the server has a PACS (and this user may use it).
  async start() {
    try {
      this.pacs = (await getJson('/api/pacs')).pacs;
    } catch {
      this.pacs = [];
    }
    this.panel.hidden = this.pacs.length === 0;
    const select = this.form.elements.pacs;
    select.replaceChildren(...this.pacs.map((name) => new Option(name, name)));
    select.closest('label').hidden = this.pacs.length < 2;
    return this.pacs.length > 0;
  }

  say(words) {
    this.message.textContent = words;
    this.message.hidden = !words;
  }

  async search() {
    const f = this.form.elements;
    const params = new URLSearchParams({ pacs: f.pacs.value });
    for (const key of ['PatientID', 'PatientName', 'AccessionNumber', 'ModalitiesInStudy']) {
      if (f[key].value.trim()) params.set(key, f[key].value.trim());
    }
    const day = (v) => v.replaceAll('-', '');
    if (f.from.value || f.to.value) params.set('StudyDate', `${day(f.from.value)}-${day(f.to.value)}`);
    this.say('Searching…');
    this.seriesList.replaceChildren();
    try {
      this.showStudies(await getJson(`/api/pacs/studies?${params}`));
    } catch (e) {
      this.studyList.replaceChildren();
      this.say(`The search failed: ${e.message}`);
    }
  }

  // Lists `studies` (found on a PACS); a click lists a study's series.
  showStudies(studies) {
    this.say(studies.length ? '' : 'No studies match.');
    this.studyList.replaceChildren(...studies.map((s) => {
      const item = document.createElement('li');
      const button = document.createElement('button');
      button.type = 'button';
      button.dataset.study = s.study_uid;
      const who = [s.patient_name ? personName(s.patient_name) : '', s.patient_id ? `ID ${s.patient_id}` : ''];
      const what = [s.study_date ? isoDate(s.study_date) : '', s.modalities.join('/'), s.description || '',
        s.series != null ? `${s.series} series` : '', s.instances != null ? `${s.instances} images` : ''];
      button.textContent = `${who.filter(Boolean).join(' · ')} — ${what.filter(Boolean).join(' · ')}`;
      button.addEventListener('click', () => this.listSeries(s.pacs, s.study_uid));
      item.append(button);
      return item;
    }));
  }

  async listSeries(pacs, study) {
    this.say('Listing the series…');
    try {
      const series = await getJson(`/api/pacs/series?${new URLSearchParams({ pacs, study })}`);
      this.showSeries(pacs, study, series);
      this.say(series.length ? '' : 'This study has no series.');
    } catch (e) {
      this.say(`Cannot list the series: ${e.message}`);
    }
  }

  // Lists a study's series, each with an Open button (or why it cannot be
  // a volume).
  showSeries(pacs, study, series) {
    this.seriesList.replaceChildren(...series.map((s) => {
      const item = document.createElement('li');
      item.dataset.series = s.series_uid;
      const words = [s.number != null ? `#${s.number}` : '', s.modality || '', s.description || '(no description)',
        s.instances != null ? `${s.instances} image${s.instances === 1 ? '' : 's'}` : ''];
      const label = document.createElement('span');
      label.textContent = words.filter(Boolean).join(' · ');
      const thumb = document.createElement('img');
      thumb.alt = '';
      thumb.className = 'thumbnail';
      item.append(thumb, label);
      this.thumbnail(thumb, pacs, study, s.series_uid);
      if (s.volume) {
        const open = document.createElement('button');
        open.type = 'button';
        open.textContent = s.cached ? 'Show' : 'Open';
        open.addEventListener('click', () => this.open(pacs, study, s.series_uid));
        item.append(' ', open);
      } else {
        item.append(' — not a volume');
      }
      return item;
    }));
  }

  // Loads a series' thumbnail (as the PACS renders it) into `img`; without
  // one the image stays empty.
  async thumbnail(img, pacs, study, series) {
    try {
      const response = await authFetch(`/api/pacs/thumbnail?${new URLSearchParams({ pacs, study, series })}`);
      if (!response.ok) return;
      img.addEventListener('load', () => URL.revokeObjectURL(img.src), { once: true });
      img.src = URL.createObjectURL(await response.blob());
      img.dataset.loaded = '1';
    } catch {
      // No thumbnail: the series is listed without one.
    }
  }

  // Opens a series: the server fetches and bricks it; resolves with the
  // dataset's id once it is offered, or rejects with why not.
  async open(pacs, study, series) {
    const params = new URLSearchParams({ pacs, study, series });
    let previewed = false;
    try {
      let job = await getJson(`/api/pacs/open?${params}`, { method: 'POST' });
      while (job.state === 'fetching' || job.state === 'bricking') {
        if (job.preview && !previewed) {
          previewed = true;
          this.onProgress(null);
          await this.onOpened(job.dataset, { preview: true });
        }
        if (previewed) this.onPreviewProgress(...progressOf(job));
        else this.onProgress(...progressOf(job));
        await new Promise((resolve) => setTimeout(resolve, POLL_MS));
        job = await getJson(`/api/pacs/open?${params}`);
      }
      if (job.state !== 'ready') throw new Error(job.error || `the series is ${job.state}`);
      this.onProgress(null);
      this.onPreviewProgress(null);
      await this.onOpened(job.dataset, { again: previewed });
      return job.dataset;
    } catch (e) {
      this.onProgress(null);
      this.onPreviewProgress(null);
      this.say(`Cannot open the series: ${e.message}`);
      throw e;
    }
  }

  // An IHE Invoke Image Display request (its query string): a study is
  // listed and its volume opened; a patient's studies are listed. Rejects
  // with words for the user when there is nothing to show.
  async invoke(query) {
    const resolved = await getJson(`/api/pacs/iid?${query}`);
    this.showStudies(resolved.studies);
    if (!resolved.show) {
      this.panel.open = true;
      return null;
    }
    const study = resolved.studies[0];
    this.showSeries(study.pacs, study.study_uid, resolved.series);
    return this.open(study.pacs, study.study_uid, resolved.show);
  }
}
